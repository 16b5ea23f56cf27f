"""Camera geometry, batched, for numpy arrays and torch tensors alike.

Conventions (docs/design.md §2):

* Camera frame: x right, y down, z forward, metres.
* Pixel (u, v): u to the right, v down, origin at the centre of the top-left pixel.
* ``T_{1→2}`` (4×4) maps a point in camera-1 coordinates to camera-2 coordinates: ``p2 = R p1 + t``.
* KITTI poses are camera-to-world; the relative pose between frames i and j is
  ``T_{i→j} = inv(Pose_j) · Pose_i``.

Every function takes numpy arrays or torch tensors (any leading batch dimensions) and returns the
same kind. Torch inputs keep their device, dtype and autograd graph.
"""

from __future__ import annotations

from typing import Any

import numpy as np

Array = Any  # np.ndarray | torch.Tensor


def _is_torch(x: Array) -> bool:
    return type(x).__module__.startswith("torch")


def _stack(xs: list[Array], axis: int) -> Array:
    if _is_torch(xs[0]):
        import torch

        return torch.stack(xs, dim=axis)
    return np.stack(xs, axis=axis)


def _cat(xs: list[Array], axis: int) -> Array:
    if _is_torch(xs[0]):
        import torch

        return torch.cat(xs, dim=axis)
    return np.concatenate(xs, axis=axis)


def _transpose_last(x: Array) -> Array:
    return x.transpose(-1, -2) if _is_torch(x) else np.swapaxes(x, -1, -2)


def _copy(x: Array) -> Array:
    return x.clone() if _is_torch(x) else np.array(x, copy=True)


def _like(x: Array, values: Array) -> Array:
    """``values`` (numpy) as the array kind, dtype and device of ``x``."""
    if _is_torch(x):
        import torch

        return torch.as_tensor(np.asarray(values), dtype=x.dtype, device=x.device)
    return np.asarray(values, dtype=x.dtype)


# --------------------------------------------------------------------------- intrinsics


def scale_intrinsics(K: Array, sx: float, sy: float) -> Array:
    """Intrinsics after resizing the image by (sx, sy) (new width = sx · old width).

    The first row of K scales by sx, the second by sy. With pixel centres at integer coordinates the
    exact map is ``u' = sx (u + 0.5) − 0.5``; KITTI tooling (and SC-SfMLearner) ignores the half-pixel
    term, and so do we, so that K stays consistent with the released preprocessing.
    """
    out = _copy(K)
    out[..., 0, :] = out[..., 0, :] * sx
    out[..., 1, :] = out[..., 1, :] * sy
    return out


def crop_intrinsics(K: Array, left: float, top: float) -> Array:
    """Intrinsics after cropping ``left`` columns and ``top`` rows off the image (pixels)."""
    out = _copy(K)
    out[..., 0, 2] = out[..., 0, 2] - left
    out[..., 1, 2] = out[..., 1, 2] - top
    return out


def camera_offset_from_projection(P: Array) -> Array:
    """4×4 transform from rectified cam0 coordinates to the camera of the rectified projection ``P`` (3×4).

    KITTI's ``P_i = K_i [I | t_i]``, so a cam0 point X is ``X + t_i`` in camera i with
    ``t_i = K_i⁻¹ P_i[:, 3]``; for the colour camera image_2 this is ≈ (+0.06, 0, 0) m, i.e. x ≈
    ``P2[0,3] / P2[0,0]``.
    """
    P64 = np.asarray(P, dtype=np.float64)
    t = np.linalg.solve(P64[:3, :3], P64[:3, 3])
    T = np.eye(4)
    T[:3, 3] = t
    return T


# --------------------------------------------------------------------------- SE(3)


def se3_inverse(T: Array) -> Array:
    """Inverse of rigid transforms T (…, 4, 4): ``[Rᵀ | −Rᵀ t]``."""
    R = T[..., :3, :3]
    t = T[..., :3, 3:4]
    Rt = _transpose_last(R)
    out = _copy(T)
    out[..., :3, :3] = Rt
    out[..., :3, 3:4] = -(Rt @ t)
    out[..., 3, :3] = 0
    out[..., 3, 3] = 1
    return out


def se3_compose(A: Array, B: Array) -> Array:
    """``A · B`` (apply B first, then A)."""
    return A @ B


def relative_pose(pose_i: Array, pose_j: Array) -> Array:
    """``T_{i→j} = inv(Pose_j) · Pose_i`` from camera-to-world poses (…, 4, 4)."""
    return se3_inverse(pose_j) @ pose_i


def transform_points(T: Array, points: Array) -> Array:
    """Apply T (…, 4, 4) to points (…, N, 3): ``R p + t``."""
    R = T[..., :3, :3]
    t = T[..., :3, 3]
    return points @ _transpose_last(R) + t[..., None, :]


def static_flow(points: Array, T_1to2: Array, *, as_float32: bool = False) -> Array:
    """The flow the camera's motion alone explains (a rigid scene): ``sf_s = (R p + t) − p`` (the paper's eq. 11).

    ``points`` (…, N, 3): camera-1 frame (x right, y down, z forward), metres. ``T_1to2`` (…, 4, 4) =
    ``[R | t]`` is the *relative* pose that maps camera-1 coordinates to camera-2 coordinates (``p2 = R p1 +
    t``; for a pair (t, t+1), ``T_{t→t+1} = inv(Pose_{t+1}) · Pose_t`` of camera-to-world poses, see
    :func:`relative_pose`), not a camera-to-world pose. Returns (…, N, 3) metres: a static point's position in
    camera 2's coordinates minus its position in camera 1's.

    numpy or torch like every function here. ``as_float32=True`` (numpy): inputs taken as float64, result
    rounded once to float32 — the precision stage one's cache writer, the cache reader and verifier, the
    prediction export and the evaluation's static-pose method all use, so their static flows agree bit for bit.
    """
    if as_float32:
        p64 = np.asarray(points, dtype=np.float64)
        return (transform_points(np.asarray(T_1to2, dtype=np.float64), p64) - p64).astype(np.float32)
    return transform_points(T_1to2, points) - points


def to_homogeneous_3x4(M: Array) -> Array:
    """Pad 3×4 matrices (…, 3, 4) to 4×4 with the row [0, 0, 0, 1]."""
    row = _like(M, np.zeros(M.shape[:-2] + (1, 4)))
    row[..., 0, 3] = 1
    return _cat([M, row], axis=-2)


# --------------------------------------------------------------------------- Euler / 6-vector


def euler_to_matrix(angles: Array) -> Array:
    """Rotation matrices from Euler angles (…, 3) = (rx, ry, rz), radians: ``R = Rx · Ry · Rz``.

    This is SC-SfMLearner's ``euler2mat``: Rz is applied to a vector first, then Ry, then Rx.
    """
    lib = _lib(angles)
    rx, ry, rz = angles[..., 0], angles[..., 1], angles[..., 2]
    cx, sx, cy, sy, cz, sz = lib.cos(rx), lib.sin(rx), lib.cos(ry), lib.sin(ry), lib.cos(rz), lib.sin(rz)
    one, zero = lib.ones_like(rx), lib.zeros_like(rx)
    Rx = _stack([_stack([one, zero, zero], -1), _stack([zero, cx, -sx], -1), _stack([zero, sx, cx], -1)], -2)
    Ry = _stack([_stack([cy, zero, sy], -1), _stack([zero, one, zero], -1), _stack([-sy, zero, cy], -1)], -2)
    Rz = _stack([_stack([cz, -sz, zero], -1), _stack([sz, cz, zero], -1), _stack([zero, zero, one], -1)], -2)
    return Rx @ Ry @ Rz


def matrix_to_euler(R: Array) -> Array:
    """Inverse of :func:`euler_to_matrix` (…, 3, 3) → (…, 3) radians, for |ry| < 90°.

    With R = Rx·Ry·Rz: R[0,2] = sin ry, R[1,2] = −sin rx cos ry, R[2,2] = cos rx cos ry,
    R[0,1] = −cos ry sin rz, R[0,0] = cos ry cos rz.
    """
    lib = _lib(R)
    ry = lib.arcsin(lib.clip(R[..., 0, 2], -1.0, 1.0)) if lib is np else lib.asin(R[..., 0, 2].clamp(-1.0, 1.0))
    atan2 = np.arctan2 if lib is np else lib.atan2
    rx = atan2(-R[..., 1, 2], R[..., 2, 2])
    rz = atan2(-R[..., 0, 1], R[..., 0, 0])
    return _stack([rx, ry, rz], -1)


def pose_vec_to_mat(vec: Array) -> Array:
    """SC-SfMLearner 6-vector (…, 6) = [tx, ty, tz, rx, ry, rz] (metres, radians) → 4×4 ``[R | t]``."""
    R = euler_to_matrix(vec[..., 3:6])
    top = _cat([R, vec[..., :3, None]], axis=-1)
    return to_homogeneous_3x4(top)


def mat_to_pose_vec(T: Array) -> Array:
    """4×4 (or 3×4) ``[R | t]`` → 6-vector [tx, ty, tz, rx, ry, rz]."""
    return _cat([T[..., :3, 3], matrix_to_euler(T[..., :3, :3])], axis=-1)


def rotation_angle(R: Array) -> Array:
    """Rotation angle of R (…, 3, 3) in radians, in [0, π].

    ``atan2(sin, cos)`` with ``sin`` = half the norm of R's skew part and ``cos = (trace − 1) / 2``: accurate to
    rounding at every angle, where ``arccos`` of the trace alone turns one ulp of the trace into ≈ 1e-8 rad
    near zero.
    """
    lib = _lib(R)
    sx = R[..., 2, 1] - R[..., 1, 2]
    sy = R[..., 0, 2] - R[..., 2, 0]
    sz = R[..., 1, 0] - R[..., 0, 1]
    sin = 0.5 * lib.sqrt(sx * sx + sy * sy + sz * sz)
    cos = (R[..., 0, 0] + R[..., 1, 1] + R[..., 2, 2] - 1.0) / 2.0
    return np.arctan2(sin, cos) if lib is np else lib.atan2(sin, cos)


# --------------------------------------------------------------------------- pixels <-> points


def pixel_grid(height: int, width: int, like: Array | None = None) -> Array:
    """(H, W, 2) pixel coordinates (u, v) of every pixel centre, as float64 numpy or like ``like``."""
    v, u = np.meshgrid(np.arange(height, dtype=np.float64), np.arange(width, dtype=np.float64), indexing="ij")
    grid = np.stack([u, v], axis=-1)
    return grid if like is None else _like(like, grid)


def backproject(depth: Array, K: Array, uv: Array | None = None) -> Array:
    """Back-project depth to camera-frame points: ``P = D · K⁻¹ [u, v, 1]ᵀ``.

    Dense: ``depth`` (…, H, W) with ``uv=None`` → points (…, H, W, 3).
    Sparse: ``depth`` (…, N) with ``uv`` (…, N, 2) → points (…, N, 3).
    ``K`` is (…, 3, 3) (broadcast over the batch). Depth is z in metres.
    """
    if uv is None:
        H, W = depth.shape[-2], depth.shape[-1]
        uv = pixel_grid(H, W, like=depth)
        Kb = K[..., None, None, :, :]
    else:
        Kb = K[..., None, :, :]
    fx, fy, cx, cy = Kb[..., 0, 0], Kb[..., 1, 1], Kb[..., 0, 2], Kb[..., 1, 2]
    s = Kb[..., 0, 1]
    v = uv[..., 1]
    y = (v - cy) / fy
    x = (uv[..., 0] - cx - s * y) / fx
    return _stack([x * depth, y * depth, depth], -1)


def project(points: Array, K: Array, eps: float = 1e-6) -> tuple[Array, Array]:
    """Project camera-frame points (…, N, 3) with K (…, 3, 3) → (uv (…, N, 2) pixels, z (…, N) metres).

    Points with z ≤ eps get their z clamped to eps for the division; callers mask them with ``z > eps``.
    """
    z = points[..., 2]
    lib = _lib(points)
    zs = lib.clip(z, eps, None) if lib is np else z.clamp(min=eps)
    Kb = K[..., None, :, :]
    x, y = points[..., 0] / zs, points[..., 1] / zs
    u = Kb[..., 0, 0] * x + Kb[..., 0, 1] * y + Kb[..., 0, 2]
    v = Kb[..., 1, 1] * y + Kb[..., 1, 2]
    return _stack([u, v], -1), z


def in_image(uv: Array, height: int, width: int) -> Array:
    """Mask of pixel coordinates inside the image (pixel centres span [0, W−1] × [0, H−1])."""
    return (uv[..., 0] >= 0) & (uv[..., 0] <= width - 1) & (uv[..., 1] >= 0) & (uv[..., 1] <= height - 1)


def _lib(x: Array):
    if _is_torch(x):
        import torch

        return torch
    return np
