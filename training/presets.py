"""Named training presets: the settings ``make demo`` trains with, in one place for the demo, the
learning-curve benchmark and the tests."""

from __future__ import annotations

from typing import Any


def demo_train_config(cache: str, run_dir: str, steps: int = 500, n_points: int = 2048, width_scale: float = 0.5,
                      seed: int = 0, overrides: dict[str, Any] | None = None):
    """The demo's :class:`~training.config.TrainConfig`: a half-width net at 2048 points, batch 4, on
    geometry alone (the LiDAR-like test splits have no colours), with the rigid ego-motion head, a warping
    cost volume at the finest level (``model.l0_cost_volume``: at 2048 points the paper's net matches last
    at 256), a per-point layer norm instead of batch norm (``model.norm``) with the ego-motion term
    (``loss.ego_motion``: the head's rigid motion against stage one's static flow), the camera-to-LiDAR
    augmentations and camera speeds rescaled ×½ … ×2 (``data.ego_speed_scale``; docs/learned-flow.md,
    seventh and eighth rounds), frame 2 pre-aligned by the voted camera translation
    (``model.translation_vote``, tenth round), the ego head's gate straight-through with flow heads that start
    at zero (``model.ego_open_gradient``, ``model.zero_flow_heads``, eleventh round), the own flows it holds
    pulled back to its output (``loss.gate_pull``) and the Chamfer term truncated at 2 m
    (``loss.chamfer_truncate``, twelfth round), the Chamfer and Laplacian terms counted along frame 2's surface
    normals (``loss.chamfer_plane``, ``loss.laplacian_plane``, fourteenth round) with the flow's departures
    from the camera's motion kept smooth over frame t (``loss.flow_smooth``, fifteenth round: with these
    three, longer training no longer makes the net worse), and at inference the flow anchored to the
    camera's measured motion (``model.eval_anchor``: the rigid vote, the finest level held at the vote's motion, a
    departure taken only where frame 2 supports it; twentieth round), the vote's rigid rounds matching frame 2's
    whole input and its choice weighed by range (``model.rigid_vote_dense``, ``model.rigid_vote_far``,
    twenty-first round) and a departure taken only where a point's neighbourhood departs with it
    (``model.eval_gate_k``, twenty-second round), the vote's rounds started at the camera's turn scanned within
    ±6° (``model.rigid_vote_yaw_deg``, thirty-second round) and frame 2's support for a departure read from its
    whole input (``model.eval_evidence_dense``, thirty-fourth round) and the vote's choice among its hypotheses
    made by the mean gap from frame 1 to frame 2 (``model.rigid_vote_gap_m``, thirty-fifth round), each hypothesis also
    started along the camera's optical axis (``model.rigid_vote_forward``, thirty-seventh round) and also refined with
    each point weighed by its neighbourhood's density (``model.rigid_vote_density_m``, thirty-eighth round), and the
    finest level's departures measured from the net's own camera motion (``model.eval_own_departure``, thirty-ninth
    round) and a point whose target under the vote's motion leaves frame 2's view held at it unless it departs
    with its in-view neighbours (``model.eval_view_hold``, fortieth round), each departure kept along the ground
    (``model.eval_level_departure``, forty-second round) and taken only where the camera's motion leaves the
    point's neighbourhood off frame 2's sampled surface (``model.eval_evidence_surface`` 1.5 spacings, forty-third
    round);
    the paper's step decay of the learning rate (×0.7) counted every ten passes over the training pairs
    (``optim.decay_every_epochs``: the paper's 200k samples are about ten passes over FlyingThings3D; counted
    in samples it would never decay on a cache of a few hundred pairs), which on the demo's 216 pairs first
    decays at step 540, after the demo's 500 (forty-ninth round);
    ``overrides`` are dotted
    ``{"model.ego_head": False}`` pairs."""
    from core.options import config_from_dict
    from training.config import TrainConfig, level_points_for

    base: dict[str, Any] = {
        "cache": cache, "run_dir": run_dir, "steps": steps, "seed": seed, "device": "auto",
        "log_every": max(1, steps // 20), "val_every": max(1, steps // 5), "ckpt_every": max(1, steps // 5),
        "data": {"n_points": n_points, "workers": 1, "colour_features": False,
                 "lidar_rings": 0.5, "density_drop": 0.3, "ground_jitter_m": 0.3, "ego_speed_scale": [0.5, 2.0]},
        "optim": {"batch_size": 4, "decay_every_epochs": 10.0},
        "loss": {"ego_motion": 1.0, "gate_pull": 1.0, "chamfer_truncate": 2.0, "chamfer_plane": 1.0,
                 "laplacian_plane": 1.0, "flow_smooth": 0.3},
        "model": {"n_points": n_points, "level_points": list(level_points_for(n_points)), "width_scale": width_scale,
                  "ego_head": True, "l0_cost_volume": True, "norm": "layer",
                  "translation_vote": True, "ego_open_gradient": True, "zero_flow_heads": True,
                  "eval_anchor": True, "rigid_vote_dense": True, "rigid_vote_far": True,
                  "eval_gate_k": 16, "rigid_vote_yaw_deg": 6.0, "eval_evidence_dense": True,
                  "rigid_vote_gap_m": 0.3, "rigid_vote_forward": True, "rigid_vote_density_m": 0.62,
                  "eval_own_departure": True, "eval_view_hold": True, "eval_level_departure": True,
                  "eval_evidence_surface": 1.5},
    }
    return config_from_dict(TrainConfig, base, overrides, source="demo preset")
