"""Addressable random numbers: every number is a function of (seed, pixel, sample, dimension).

A renderer that plugs into the adaptive sampler receives requests for *specific* sample indices
of specific pixels (``first_index .. first_index + count - 1``). To make the result independent
of how the work was split into requests, rounds, batches or threads, no random number here
comes from a stateful generator: each one is a hash of its address. Rendering samples 0-7 of a
pixel in one request or as 0-3 and 4-7 in two requests therefore traces exactly the same paths.

Two samplers are offered:

* :class:`IndependentSampler`: a 64-bit integer hash (SplitMix64 finaliser) of the address,
  53 bits turned into a float in [0, 1).
* :class:`SobolSampler`: padded 2D Sobol' points (Sobol' dimensions 0 and 1), Owen-scrambled
  and index-shuffled per pixel and per dimension pair with hash-based nested uniform
  scrambling (Burley 2020, "Practical Hash-based Owen Scrambling"). Shuffling the sample index
  with an Owen scramble maps every aligned block of ``2^k`` indices onto an aligned block, so
  the first ``2^k`` samples of a pixel still form a (0, k, 2)-net in every dimension pair while
  each number stays a pure function of its sample index.

Both draw per-pixel seeds from the hash, so pixel estimates are independent across pixels, as
the variance propagation of the paper (section 3; docs/concepts.md, "Sample buffer") assumes.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = [
    "SAMPLER_NAMES",
    "hash_u64",
    "mix_u64",
    "u64_to_unit_float",
    "IndependentSampler",
    "SobolSampler",
    "make_sampler",
    "sobol_2d",
    "nested_uniform_scramble",
]

SAMPLER_NAMES = ("independent", "sobol")
"""Valid values of the ``sampler`` parameter."""

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX_1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX_2 = np.uint64(0x94D049BB133111EB)
_U32_MASK = np.uint64(0xFFFFFFFF)


def _dimension_salt(dimension: int) -> np.uint64:
    # Python integers do the wrapping product, so no numpy scalar overflow warning is raised.
    return np.uint64(((int(dimension) + 1) * 0x9E3779B97F4A7C15) & 0xFFFFFFFFFFFFFFFF)


def mix_u64(x: np.ndarray) -> np.ndarray:
    """SplitMix64 finaliser: a bijective avalanche mix of uint64 arrays (wraps on overflow)."""
    x = np.asarray(x, dtype=np.uint64)
    x = (x ^ (x >> np.uint64(30))) * _MIX_1
    x = (x ^ (x >> np.uint64(27))) * _MIX_2
    return x ^ (x >> np.uint64(31))


def hash_u64(*keys: np.ndarray | int) -> np.ndarray:
    """Hash a sequence of integer keys (arrays broadcast) into one uint64 per element.

    Keys are folded in order, ``h = mix(h ^ key) + golden``, so ``hash_u64(a, b)`` differs from
    ``hash_u64(b, a)``.
    """
    h = np.atleast_1d(np.asarray(0x2545F4914F6CDD1D, dtype=np.uint64))
    for key in keys:
        k = np.atleast_1d(np.asarray(key)).astype(np.uint64)
        h = mix_u64(h ^ k) + _GOLDEN
    return mix_u64(h)


def u64_to_unit_float(h: np.ndarray) -> np.ndarray:
    """The top 53 bits of a uint64 as a float64 in [0, 1)."""
    return (h >> np.uint64(11)).astype(np.float64) * (1.0 / 9007199254740992.0)


# ---------------------------------------------------------------------------- Sobol' pieces
def _reverse_bits_u32(x: np.ndarray) -> np.ndarray:
    x = x.astype(np.uint32)
    x = ((x >> np.uint32(1)) & np.uint32(0x55555555)) | ((x & np.uint32(0x55555555)) << np.uint32(1))
    x = ((x >> np.uint32(2)) & np.uint32(0x33333333)) | ((x & np.uint32(0x33333333)) << np.uint32(2))
    x = ((x >> np.uint32(4)) & np.uint32(0x0F0F0F0F)) | ((x & np.uint32(0x0F0F0F0F)) << np.uint32(4))
    x = ((x >> np.uint32(8)) & np.uint32(0x00FF00FF)) | ((x & np.uint32(0x00FF00FF)) << np.uint32(8))
    return (x >> np.uint32(16)) | (x << np.uint32(16))


def _laine_karras_permutation(x: np.ndarray, seed: np.ndarray) -> np.ndarray:
    # Burley 2020, listing 3 (improved constants): a hash that only lets bits influence
    # *higher* bits, i.e. an Owen scramble when applied to bit-reversed input.
    x = x + seed
    x ^= x * np.uint32(0x6C50B47C)
    x ^= x * np.uint32(0xB82F1E52)
    x ^= x * np.uint32(0xC7AFE638)
    x ^= x * np.uint32(0x8D22F6E6)
    return x


def nested_uniform_scramble(x: np.ndarray, seed: np.ndarray) -> np.ndarray:
    """Hash-based Owen (nested uniform) scrambling of 32-bit fixed-point values (Burley 2020)."""
    x = _reverse_bits_u32(x)
    x = _laine_karras_permutation(x, seed.astype(np.uint32))
    return _reverse_bits_u32(x)


def _sobol_dim1_tables() -> np.ndarray:
    # Direction numbers of the second Sobol' dimension (primitive polynomial x + 1), folded
    # into four 256-entry XOR tables, one per byte of the index: four gathers replace a loop
    # over 32 bits.
    v = np.zeros(32, np.uint32)
    v[0] = 1 << 31
    for i in range(1, 32):
        v[i] = v[i - 1] ^ (v[i - 1] >> 1)
    tables = np.zeros((4, 256), np.uint32)
    for byte in range(4):
        for value in range(256):
            acc = 0
            for bit in range(8):
                if value >> bit & 1:
                    acc ^= int(v[8 * byte + bit])
            tables[byte, value] = acc
    return tables


_SOBOL_DIM1_TABLES = _sobol_dim1_tables()


def sobol_2d(index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The first two Sobol' dimensions of 32-bit ``index`` as uint32 fixed-point values."""
    index = np.asarray(index).astype(np.uint32)
    x = _reverse_bits_u32(index)  # dimension 0 is the van der Corput sequence
    y = _SOBOL_DIM1_TABLES[0][index & np.uint32(0xFF)]
    for byte in range(1, 4):
        y = y ^ _SOBOL_DIM1_TABLES[byte][(index >> np.uint32(8 * byte)) & np.uint32(0xFF)]
    return x, y


# ---------------------------------------------------------------------------- samplers
class IndependentSampler:
    """Independent uniform numbers hashed from (seed, pixel, sample index, dimension).

    Parameters
    ----------
    seed
        Render seed; different seeds give independent renders.
    """

    name = "independent"

    def __init__(self, seed: int = 0) -> None:
        self.seed = int(seed)

    def start(self, pixel: np.ndarray, sample_index: np.ndarray) -> np.ndarray:
        """Per-sample base key; pass it to :meth:`get`."""
        return hash_u64(self.seed, pixel, sample_index)

    def get(self, key: np.ndarray, dimension: int, *, pixel: np.ndarray | None = None,
            sample_index: np.ndarray | None = None, group: Sequence[int] = ()) -> np.ndarray:
        """Float64 numbers in [0, 1) of ``dimension`` for the samples whose base key is ``key``."""
        return u64_to_unit_float(mix_u64(key ^ _dimension_salt(dimension)))


class SobolSampler:
    """Padded, Owen-scrambled, index-shuffled 2D Sobol' points (Burley 2020).

    Dimensions are consumed in pairs (``group``): the two dimensions of a pair are the two
    Sobol' dimensions of one shuffled index, so each pair (pixel position, lens position, light
    sample, bounce direction) is stratified on its own. Different pairs and different pixels use
    independent shuffles and scrambles (padding), so pixels stay independent.
    """

    name = "sobol"

    def __init__(self, seed: int = 0) -> None:
        self.seed = int(seed)

    def start(self, pixel: np.ndarray, sample_index: np.ndarray) -> np.ndarray:
        """Per-pixel base key (the sample index enters through the shuffled Sobol' index)."""
        index = np.asarray(sample_index)
        if index.size and int(index.max()) >= 2**32:  # cast to 32 bits, sample 2**32 + k would be sample k again
            raise ValueError(f"sample_index: {int(index.max())} is past the Sobol' sampler's 2**32 points a pixel; "
                             "render past them with sampler='independent'")
        return hash_u64(self.seed, pixel)

    def get(self, key: np.ndarray, dimension: int, *, pixel: np.ndarray | None = None,
            sample_index: np.ndarray | None = None, group: Sequence[int] = ()) -> np.ndarray:
        """Numbers of ``dimension``; ``group`` lists the 1 or 2 dimensions of its Sobol' pair."""
        if sample_index is None:
            raise ValueError("sample_index: the Sobol' sampler needs the sample indices")
        group = tuple(group) if group else (dimension,)
        pair_key = mix_u64(key ^ _dimension_salt(group[0]))
        shuffle_seed = (pair_key & _U32_MASK).astype(np.uint32)
        index = nested_uniform_scramble(np.asarray(sample_index).astype(np.uint32), shuffle_seed)
        x, y = sobol_2d(index)
        component = group.index(dimension)
        value = x if component == 0 else y
        scramble_seed = (mix_u64(pair_key + np.uint64(component + 1)) & _U32_MASK).astype(np.uint32)
        scrambled = nested_uniform_scramble(value, scramble_seed)
        # 32-bit fixed point to float64: exactly representable, always in [0, 1).
        return scrambled.astype(np.float64) * (1.0 / 4294967296.0)


def make_sampler(name: str, seed: int = 0) -> IndependentSampler | SobolSampler:
    """The sampler called ``name`` (one of :data:`SAMPLER_NAMES`)."""
    if name == "independent":
        return IndependentSampler(seed)
    if name == "sobol":
        return SobolSampler(seed)
    raise ValueError(f"sampler: {name!r} is not one of {', '.join(SAMPLER_NAMES)}")
