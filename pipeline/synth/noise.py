"""Deterministic hashed value noise (2-D and 3-D) and its multi-octave sums, vectorised in numpy.

A lattice value is a 64-bit integer hash (splitmix64 finaliser) of the lattice coordinates and a seed,
so the noise is a pure function of its inputs: the same surface point gets the same value in every
frame, on every machine.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

_P = (np.uint64(0x9E3779B97F4A7C15), np.uint64(0xC2B2AE3D27D4EB4F), np.uint64(0x165667B19E3779F9))
_C1, _C2 = np.uint64(0xBF58476D1CE4E5B9), np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31, _S11 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11)


def hash_unit(seed: int, *ints: np.ndarray) -> np.ndarray:
    """Uniform values in [0, 1) hashed from integer arrays (broadcast together) and a seed."""
    z = np.full(np.broadcast(*ints).shape, (seed * 0xD6E8FEB86659FD93) & 0xFFFFFFFFFFFFFFFF, dtype=np.uint64)
    for k, a in enumerate(ints):
        z += np.asarray(a, dtype=np.int64).astype(np.uint64) * _P[k % 3]
    z ^= z >> _S30
    z *= _C1
    z ^= z >> _S27
    z *= _C2
    z ^= z >> _S31
    return (z >> _S11).astype(np.float64) * (1.0 / 9007199254740992.0)


def _fade(t: np.ndarray) -> np.ndarray:
    return t * t * (3.0 - 2.0 * t)


_N = 256  # lattice period of one noise octave
_TABLE = hash_unit(0x7AB1E, np.arange(_N)[:, None], np.arange(_N)[None, :]).ravel()  # values at lattice points
_PERM = (hash_unit(0x9E12, np.arange(_N)) * _N).astype(np.int64)


@lru_cache(maxsize=4096)
def _offsets(seed: int) -> tuple[int, int]:
    h = hash_unit(seed, np.array([1, 2]))
    return int(h[0] * _N), int(h[1] * _N)


def noise2(x: np.ndarray, y: np.ndarray, seed: int) -> np.ndarray:
    """Value noise in [0, 1] with unit lattice spacing, smooth (C¹) between lattice points.

    Lattice values come from a fixed 256×256 table (periodic over 256 lattice cells), shifted per seed.
    """
    xf, yf = np.floor(x), np.floor(y)
    ox, oy = _offsets(seed)
    ix = (xf.astype(np.int64) + ox) & (_N - 1)
    iy = (yf.astype(np.int64) + oy) & (_N - 1)
    ix1, iy1 = (ix + 1) & (_N - 1), (iy + 1) * _N & (_N * _N - 1)
    iy = iy * _N
    u, v = _fade(x - xf), _fade(y - yf)
    a, b = _TABLE[iy + ix], _TABLE[iy + ix1]
    c, d = _TABLE[iy1 + ix], _TABLE[iy1 + ix1]
    ab = a + (b - a) * u
    return ab + (c + (d - c) * u - ab) * v


def noise3(x: np.ndarray, y: np.ndarray, z: np.ndarray, seed: int) -> np.ndarray:
    """3-D value noise in [0, 1] with unit lattice spacing (the z lattice index permutes the x row)."""
    xf, yf, zf = np.floor(x), np.floor(y), np.floor(z)
    ox, oy = _offsets(seed)
    ix = xf.astype(np.int64) + ox
    iy = yf.astype(np.int64) + oy
    iz = zf.astype(np.int64)
    u, v, w = _fade(x - xf), _fade(y - yf), _fade(z - zf)
    out = np.zeros(np.shape(x))
    for dz in (0, 1):
        pz = _PERM[(iz + dz) & (_N - 1)]
        wz = w if dz else 1.0 - w
        for dy in (0, 1):
            row = ((iy + dy) & (_N - 1)) * _N
            wy = v if dy else 1.0 - v
            a = _TABLE[row + ((ix + pz) & (_N - 1))]
            b = _TABLE[row + ((ix + pz + 1) & (_N - 1))]
            out += wz * wy * (a + (b - a) * u)
    return out


def _fbm(noise, coords: tuple, seed: int, base_freq: float, octaves: int, gain: float, fp) -> np.ndarray:
    total = np.zeros(np.shape(coords[0]))
    amp, norm, f = 1.0, 0.0, base_freq
    for o in range(octaves):
        if fp is None:
            total += amp * noise(*(c * f for c in coords), seed + 7919 * o)
        else:
            # prefiltering: an octave fades to its mean 0.5 as its wavelength shrinks to 1.5 footprints
            w = np.clip(1.0 / (f * fp) - 1.5, 0.0, 1.0)
            sel = np.flatnonzero(w > 0)
            total += amp * 0.5
            if len(sel) == len(w):
                total += amp * w * (noise(*(c * f for c in coords), seed + 7919 * o) - 0.5)
            elif len(sel):
                total[sel] += amp * w[sel] * (noise(*(c[sel] * f for c in coords), seed + 7919 * o) - 0.5)
        norm += amp
        amp *= gain
        f *= 2.0
    return total / norm


def fbm2(x: np.ndarray, y: np.ndarray, seed: int, base_freq: float, octaves: int, gain: float = 0.5,
         fp: np.ndarray | None = None) -> np.ndarray:
    """Sum of ``octaves`` noise2 octaves (frequency ×2, amplitude ×gain each), normalised to [0, 1].

    ``base_freq`` is in cycles per unit of the inputs. ``fp`` (same shape as x, input units) is the
    sampling footprint: octaves whose wavelength approaches it fade to their mean (a prefiltered
    texture, so that distant detail does not alias); None keeps every octave.
    """
    return _fbm(noise2, (x, y), seed, base_freq, octaves, gain, fp)


def fbm3(x, y, z, seed: int, base_freq: float, octaves: int, gain: float = 0.5, fp=None) -> np.ndarray:
    """3-D counterpart of :func:`fbm2`."""
    return _fbm(noise3, (x, y, z), seed, base_freq, octaves, gain, fp)
