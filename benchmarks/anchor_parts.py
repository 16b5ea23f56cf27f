"""Which parts of the inference anchor matter: trained nets scored with each named subset of its switches.

``model.eval_anchor`` (:class:`training.model.halflownet_config.HALFlowConfig`) turns three no-learning
switches on at inference: the rigid vote, the finest level held at the vote's camera motion, the evidence
gate; the parts also include the hold at L1's motion (the nineteenth round's).
This tool restores each checkpoint, sets one subset of them on the restored net (the weights are untouched:
none of the three has any) and scores it on every split under the fps protocol, so the parts can be compared
on the same points. Used for docs/learned-flow.md (twentieth round)::

    python -m benchmarks.anchor_parts --checkpoint runs/pre-w0-s0/step_000500.pt \\
        --split own=w0/world/sceneflow/flownet3d --split realr=w/real_kitti_rescan --parts none,rv,rvhe,all

``--leave-one-out`` scores each net instead as trained and with each inference-only switch it has on
(:data:`LEAVE_ONE_OUT`) turned off alone, every other one as trained: what each switch adds to the rest
(docs/learned-flow.md, forty-eighth round)::

    python -m benchmarks.anchor_parts --leave-one-out --checkpoint cache/demo/flow_run_gt/latest.pt \\
        --split boxes=w/boxes [--protocol hplflownet --n-points 8192]
"""

from __future__ import annotations

import argparse
from dataclasses import fields, replace

from benchmarks.named_folders import named_folder
from core.errors import ConfigError, run_cli
from training.model.halflownet_config import ANCHOR_SWITCHES

_L1 = {"ego_l0_hold": True, "ego_l0_hold_from": "l1"}
_VOTE = {"ego_l0_hold": True, "ego_l0_hold_from": "vote"}
_OFF = {"rigid_vote": False, "rigid_vote_dense": False, "rigid_vote_far": False, "ego_l0_hold": False,
        "ego_gate_evidence": False, "eval_evidence_dense": False, "rigid_vote_gap_m": 0.0}
_PRESET_STEPS: tuple[tuple[str, dict[str, object]], ...] = (
    ("d", {"rigid_vote_dense": True}), ("f", {"rigid_vote_far": True}), ("k", {"ego_gate_k": 16}),
    ("x", {"eval_evidence_dense": True}), ("g", {"rigid_vote_gap_m": 0.3}), ("f", {"rigid_vote_forward": True}),
    ("d", {"rigid_vote_density_m": 0.62}), ("o", {"eval_own_departure": True}), ("v", {"eval_view_hold": True}),
    ("l", {"eval_level_departure": True}), ("s", {"eval_evidence_surface": 1.5}), ("t", {"rigid_vote_yaw_deg": 6.0}))
"""The demo preset's anchor built up one switch at a time from ``all``: each step's letter extends the part's name."""


def _preset_chain() -> dict[str, dict[str, object]]:
    """``all`` (what ``eval_anchor`` turns on, the vote neither dense nor range-weighted) and each part that adds the
    next of :data:`_PRESET_STEPS` to the one before: ``alld``, ``alldf``, … ``alldfkxgfdovlst``."""
    name, part = "all", {**ANCHOR_SWITCHES, "rigid_vote_dense": False, "rigid_vote_far": False}
    chain = {name: part}
    for letter, switch in _PRESET_STEPS:
        name, part = name + letter, {**part, **switch}
        chain[name] = part
    return chain


PARTS: dict[str, dict[str, object]] = {
    "none": _OFF,
    "he": {**_OFF, **_L1, "ego_gate_evidence": True},
    "rv": {**_OFF, "rigid_vote": True},
    "rve": {**_OFF, "rigid_vote": True, "ego_gate_evidence": True},
    "rvh": {**_OFF, "rigid_vote": True, **_L1},
    "rvhe": {**_OFF, "rigid_vote": True, **_L1, "ego_gate_evidence": True},
    "rvhv": {**_OFF, "rigid_vote": True, **_VOTE},
    **_preset_chain(),
}
"""Named subsets: ``rv`` the rigid vote, ``h`` the finest level held at L1's motion (``hv``: at the vote's),
``e`` the evidence gate; ``all`` is what ``eval_anchor`` turns on, ``alld`` that with the rigid vote matching
frame 2's whole input (``rigid_vote_dense``), ``alldf`` and its choice weighed by range (``rigid_vote_far``),
``alldfk`` that with the gate reading each point's 16 nearest points (``eval_gate_k`` 16: the preset's
anchor since the twenty-second round), ``alldfkx`` that with the evidence test read against frame 2's whole
input (``eval_evidence_dense``: the preset's since the thirty-fourth round), ``alldfkxg`` that with the vote's
choice made by its mean gap (``rigid_vote_gap_m`` 0.3 m: the preset's since the thirty-fifth round), ``alldfkxgf``
that with its hypotheses also started along the optical axis (``rigid_vote_forward``: the preset's since the
thirty-seventh round), ``alldfkxgfd`` that with its starts also refined with each point weighed by its
neighbourhood's density (``rigid_vote_density_m`` 0.62 m: the preset's since the thirty-eighth round),
``alldfkxgfdo`` that with the departures measured from the net's own camera motion (``eval_own_departure``: the
preset's since the thirty-ninth round), ``alldfkxgfdov`` that with the points whose rigid target leaves frame 2's view
held at the vote's motion unless they depart with their in-view neighbours (``eval_view_hold``: the preset's since the fortieth round),
``alldfkxgfdovl`` that with each departure kept along the ground (``eval_level_departure``: the preset's since the
forty-second round), ``alldfkxgfdovls`` that with a departure taken only where the camera's motion leaves the point's
neighbourhood off frame 2's sampled surface (``eval_evidence_surface`` 1.5: the preset's since the forty-third round),
``alldfkxgfdovlst`` that with the vote's turn scanned within ±6° (``rigid_vote_yaw_deg``: the preset's since the
thirty-second round, a net setting the parts drop with the anchor): the demo preset's whole anchor,
``none`` the net without any of them."""


LEAVE_ONE_OUT: tuple[str, ...] = (
    "eval_anchor", "rigid_vote_dense", "rigid_vote_far", "eval_gate_k", "rigid_vote_yaw_deg", "eval_evidence_dense",
    "rigid_vote_gap_m", "rigid_vote_forward", "rigid_vote_density_m", "eval_own_departure", "eval_view_hold",
    "eval_level_departure", "eval_evidence_surface", "eval_neighbourhood_scale")
"""The inference-only switches of :class:`~training.model.halflownet_config.HALFlowConfig` that ``--leave-one-out``
turns off one at a time (to the field's default, the paper's form; ``eval_anchor`` off drops every switch that acts
only through it, :meth:`~training.model.halflownet_config.HALFlowConfig.without_anchor`)."""


def without_switch(method, field: str):
    """``method`` (a :class:`evaluation.methods.NetMethod`) with the inference-only ``field`` turned off and every
    other setting as trained, renamed ``<name> [-<field>]``; None when the net has it off already."""
    if field not in LEAVE_ONE_OUT:
        raise ConfigError(f"unknown switch {field!r} (choose from {', '.join(LEAVE_ONE_OUT)})")
    config = method.net.config
    default = {f.name: f.default for f in fields(config)}[field]
    if getattr(config, field) == default:
        return None
    try:
        off = config.without_anchor() if field == "eval_anchor" else replace(config, **{field: default})
    except ConfigError as e:
        raise ConfigError(f"{method.checkpoint}: cannot turn {field} off: {e}") from None
    method.config = method.net.config = off
    method.name = f"{method.name} [-{field}]"
    return method


def leave_one_out(checkpoint: str) -> list:
    """The net of ``checkpoint`` as trained (``<checkpoint> [as trained]``) and once per switch of
    :data:`LEAVE_ONE_OUT` it has on, with that switch off (:func:`without_switch`)."""
    from evaluation.methods import NetMethod

    methods = [NetMethod(checkpoint, device="cpu", name=f"{checkpoint} [as trained]")]
    for field in LEAVE_ONE_OUT:
        m = without_switch(NetMethod(checkpoint, device="cpu", name=str(checkpoint)), field)
        if m is not None:
            methods.append(m)
    return methods


def with_parts(method, part: str):
    """``method`` (a :class:`evaluation.methods.NetMethod`) set to run with the switches of ``PARTS[part]``
    at inference (its own anchor off), renamed ``<name> [<part>]``."""
    if part not in PARTS:
        raise ConfigError(f"unknown part {part!r} (choose from {', '.join(PARTS)})")
    try:
        method.config = method.net.config = replace(method.net.config.without_anchor(), **PARTS[part])
    except (ConfigError, TypeError) as e:
        raise ConfigError(f"{method.checkpoint}: cannot run the anchor's parts: {e}") from None
    method.name = f"{method.name} [{part}]"
    return method


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="anchor_parts", description=__doc__.split("\n\n")[0])
    p.add_argument("--checkpoint", action="append", default=[], required=True, help="monoflow-train checkpoint")
    p.add_argument("--split", action="append", default=[], required=True, type=named_folder,
                   help="NAME=FOLDER of a scene-flow test split")
    which = p.add_mutually_exclusive_group()
    which.add_argument("--parts", default="none,all", help=f"comma list of {', '.join(PARTS)}")
    which.add_argument("--leave-one-out", action="store_true",
                   help="instead of --parts: each net as trained and with each inference-only switch it has on turned "
                        "off alone")
    p.add_argument("--protocol", default="fps", help="the scoring protocol (evaluation.protocols; fps: the paper's)")
    p.add_argument("--n-points", type=int, default=2048, help="points sampled per cloud")
    p.add_argument("--n-score", type=int, default=512, help="scored farthest-point samples (the net's level 0)")
    p.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    args = p.parse_args(argv)

    def run(_argv=None) -> int:
        import torch

        from benchmarks.learning_curve import score_splits
        from evaluation.methods import NetMethod
        from evaluation.readers import load_split

        if args.threads:
            torch.set_num_threads(args.threads)
        parts = [t.strip() for t in args.parts.split(",") if t.strip()]
        if args.leave_one_out:
            methods = [m for c in args.checkpoint for m in leave_one_out(c)]
        else:
            methods = [with_parts(NetMethod(c, device="cpu", name=str(c)), part) for c in args.checkpoint
                       for part in parts]
        splits = {name: load_split(folder, "auto") for name, folder in args.split}
        scores = score_splits(methods, splits, args.n_points, args.n_score, protocol=args.protocol)
        print("| net [parts] | " + " | ".join(f"{s} (overall / static / moving)" for s in splits) + " |")
        print("|---|" + "---|" * len(splits))
        for m in methods:
            cells = []
            for s in splits:
                row = scores[s][m.name]
                cells.append(" / ".join(f"{row[k]:.3f}" for k in ("EPE3D", "EPE3D_static", "EPE3D_moving") if k in row))
            print(f"| {m.name} | " + " | ".join(cells) + " |")
        return 0

    return run_cli(run)


if __name__ == "__main__":
    raise SystemExit(main())
