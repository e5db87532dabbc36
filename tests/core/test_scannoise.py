"""The compiled lidar sensor model (simd/core/_scannoise.c).

Without noise it must equal the numpy reference bit for bit (the noise-off path of the sensor
model, simd/core/sensor_model.py, copied below so that this file tests the module alone).  With
noise its stream is its own (xoshiro256++ and a ziggurat, not numpy's generator), so the tests
check the masking and clamping exactly and the noise statistically over ~1M draws: moments,
tail fractions, a chi-square on 400 equiprobable bins, a Kolmogorov-Smirnov distance against
N(0, 1), serial correlation, and (16M draws) the shape of the tail past the ziggurat's last
layer, where its own sampler answers.  Also: determinism (the k-th hit gets the k-th normal of
the seed's stream, whatever the layout, the shape, in place or not, from any thread) and the
argument checks (wrong types, dtypes, layouts, lengths, numbers raise, never crash).
"""

from __future__ import annotations

import importlib
import math
import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np
import pytest

from fleetcommon.arrays import F32, F64

if os.environ.get("FLEETSIM_NATIVE", "").strip().lower() == "native":
    sn = importlib.import_module("simd.core._scannoise")  # as on CI: the compiled fast paths must be built
else:
    sn = pytest.importorskip("simd.core._scannoise", reason="simd.core._scannoise is not built (no C compiler?)")

RMIN, RMAX = 0.12, 3.5  # the TurtleBot3 LDS-01 of simd.core.lidar.LidarSpec
BELOW_MAX = float(np.nextafter(np.float32(RMAX), np.float32(0)))
ABOVE_MAX = float(np.nextafter(np.float32(RMAX), np.float32(np.inf)))
SPECIALS = [np.inf, -np.inf, np.nan, RMAX, BELOW_MAX, ABOVE_MAX, RMIN, 0.05, 0.0, -0.0, -1.0, 1e30, -1e30, 3.3, 7.0]


def reference(raw: F32, range_min: float, range_max: float) -> F32:
    """The numpy sensor model with noise off (simd/core/sensor_model.py)."""
    out = np.array(raw, dtype=np.float32, order="C", copy=True)
    flat = out.reshape(-1)
    hit = np.flatnonzero(flat < range_max)  # inf and NaN compare false
    vals = flat[hit]
    flat.fill(np.inf)
    flat[hit] = vals
    return out


def apply(raw: F32, stddev: float, seed: int, range_min: float = RMIN, range_max: float = RMAX) -> F32:
    out = np.empty_like(raw)
    sn.apply(raw, out, range_min, range_max, stddev, seed)
    return out


def mixed_scans(rng: np.random.Generator, shape: tuple[int, ...], hit_fraction: float = 0.5) -> F32:
    """Hits in [1, 3] m; misses of every kind (>= range_max, +inf, NaN) in between."""
    raw = rng.uniform(1.0, 3.0, shape)
    miss = rng.random(shape) >= hit_fraction
    raw[miss] = rng.choice([np.inf, np.nan, RMAX, 5.0, 1e30], int(miss.sum()))
    return raw.astype(np.float32)


def special_scans(rng: np.random.Generator, n: int) -> F32:
    raw = rng.uniform(-1.0, 8.0, n).astype(np.float32)
    pick = rng.random(n) < 0.4
    raw[pick] = rng.choice(np.array(SPECIALS, dtype=np.float32), int(pick.sum()))
    return raw


def phi(x: float) -> float:
    return 0.5 * (1.0 + math.erf(x / math.sqrt(2.0)))


# ------------------------------------------------------------------------------- masking


@pytest.mark.parametrize(("range_min", "range_max"), [(RMIN, RMAX), (RMIN, 3.3), (0.0, 7.0), (-np.inf, np.inf)])
def test_without_noise_equals_the_numpy_reference_bit_for_bit(range_min: float, range_max: float) -> None:
    rng = np.random.default_rng(1)
    shapes: list[tuple[int, ...]] = [(0,), (1,), (3,), (4,), (5,), (255,), (256,), (257,), (3, 5), (0, 360)]
    shapes += [(100, 360), (2, 3, 7), ()]
    for shape in shapes:
        raw = special_scans(rng, math.prod(shape)).reshape(shape)
        want = reference(raw, range_min, range_max)
        got = apply(raw, 0.0, 7, range_min, range_max)
        assert got.shape == want.shape
        assert got.tobytes() == want.tobytes(), shape
        inplace = raw.copy()
        sn.apply(inplace, inplace, range_min, range_max, 0.0, 7)
        assert inplace.tobytes() == want.tobytes(), shape


def test_without_noise_every_special_value() -> None:
    raw = np.array(SPECIALS, dtype=np.float32)
    got = apply(raw, 0.0, 0)
    assert got.tobytes() == reference(raw, RMIN, RMAX).tobytes()
    hit = np.array([-np.inf, BELOW_MAX, RMIN, 0.05, 0.0, -0.0, -1.0, -1e30, 3.3], dtype=np.float32)
    assert np.array_equal(np.isfinite(got) | (got == -np.inf), np.isin(raw, hit))
    # not clamped without noise (as the reference): below range_min, negative and -inf stay
    at = {v: k for k, v in enumerate(SPECIALS) if not math.isnan(v)}
    assert got[at[0.05]] == np.float32(0.05)
    assert got[at[-np.inf]] == -np.inf
    assert np.signbit(got[raw.view(np.uint32) == 0x80000000]).all()  # -0.0 kept as is
    assert got[at[RMAX]] == np.inf  # exactly range_max is a miss
    assert got[at[BELOW_MAX]] == np.float32(BELOW_MAX)
    assert got[SPECIALS.index(np.nan)] == np.inf


def test_the_ranges_are_rounded_to_float32_as_numpy_compares() -> None:
    # 3.3 is not a float32: np.float32(3.3) < 3.3 is False for a float32 array, so a miss
    raw = np.array([np.float32(3.3), np.nextafter(np.float32(3.3), np.float32(0))], dtype=np.float32)
    assert np.array_equal(apply(raw, 0.0, 0, RMIN, 3.3), [np.inf, raw[1]])
    noisy = apply(raw, 1.0, 0, RMIN, 3.3)  # clamped to float32(3.3) at most
    assert noisy[0] == np.inf and RMIN <= noisy[1] <= np.float32(3.3)


def test_with_noise_misses_are_inf_and_hits_are_clamped() -> None:
    rng = np.random.default_rng(2)
    raw = special_scans(rng, 20_003)  # odd: the scalar loop after the SSE2 one runs too
    raw[:100] = -np.inf  # hits: -inf + noise is clamped to range_min
    out = apply(raw, 0.5, 11)  # noise large enough to reach both clamps often
    hit = raw < np.float32(RMAX)
    assert np.all(out[~hit] == np.inf)
    assert np.all((out[hit] >= np.float32(RMIN)) & (out[hit] <= np.float32(RMAX)))
    assert np.all(out[:100] == np.float32(RMIN))
    assert np.sum(out[hit] == np.float32(RMIN)) > 100 and np.sum(out[hit] == np.float32(RMAX)) > 100
    assert not np.isnan(out).any()


def test_with_noise_the_arithmetic_is_float32() -> None:
    # with raw 0 (and a range far away) out is the float32 product float32(z) * float32(stddev);
    # with raw 1 and the same seed, the float32 sum 1 + that product, rounded once more
    raw0 = np.zeros(4096, dtype=np.float32)
    dz = apply(raw0, 0.3, 5, -100.0, 100.0)
    out1 = apply(raw0 + np.float32(1.0), 0.3, 5, -100.0, 100.0)
    assert np.array_equal(out1, np.float32(1.0) + dz)
    assert np.mean(out1.astype(np.float64) != 1.0 + dz.astype(np.float64)) > 0.1  # float64 would differ


# ------------------------------------------------------------------------------- distribution


@pytest.fixture(scope="module")
def draws() -> F64:
    """~1M standard normals from scans of which half the beams hit, in hit order."""
    rng = np.random.default_rng(3)
    raw = mixed_scans(rng, (5_000, 400))
    sd = 0.05  # hits in [1, 3]: the clamps are more than 10 sigma away
    out = apply(raw, sd, 2024)
    hit = raw < np.float32(RMAX)
    assert np.all(out[~hit] == np.inf)
    return (out[hit].astype(np.float64) - raw[hit].astype(np.float64)) / float(np.float32(sd))


def test_noise_moments(draws: F64) -> None:
    n = draws.size
    assert n > 900_000
    mean, std = draws.mean(), draws.std()
    c = (draws - mean) / std
    skew, kurt = float(np.mean(c**3)), float(np.mean(c**4))
    # 5 standard errors each: sqrt(1/n), sqrt(1/2n), sqrt(6/n), sqrt(24/n)
    assert abs(mean) < 5 / math.sqrt(n)
    assert abs(std - 1.0) < 5 / math.sqrt(2 * n)
    assert abs(skew) < 5 * math.sqrt(6 / n)
    assert abs(kurt - 3.0) < 5 * math.sqrt(24 / n)


def test_noise_tails(draws: F64) -> None:
    n = draws.size
    a = np.abs(draws)
    for k in (1.0, 2.0, 3.0, 3.5):
        p = 2 * (1 - phi(k))  # 0.3173, 0.0455, 0.0027, 0.000465
        assert abs(np.mean(a > k) - p) < 5 * math.sqrt(p * (1 - p) / n), k
    # beyond the last layer the tail sampler answers: about n * 2.6e-4 of them, some past 4
    r = float(sn.ZIGGURAT_R)
    assert 3.6 < r < 3.7
    for k in (r, 4.0):
        expected = n * 2 * (1 - phi(k))
        assert abs(np.sum(a > k) - expected) < 5 * math.sqrt(expected) + 1, k
    assert np.sum(a > 4.0) >= 1
    assert np.sum(draws > r) > 0 and np.sum(draws < -r) > 0


def test_the_tail_beyond_the_last_layer_has_the_normal_shape() -> None:
    """16M draws give ~4000 from the tail sampler (Marsaglia's, with its rejection step): their
    spread past r must be the normal tail's, not an exponential's or a shifted one."""
    r = float(sn.ZIGGURAT_R)
    cuts = (3.7, 3.8, 4.0, 4.3, 4.6)
    beyond = np.zeros(len(cuts) + 1, dtype=np.int64)
    raw = np.zeros(4_000_000, dtype=np.float32)
    out = np.empty_like(raw)
    for seed in range(4):  # raw 0, stddev 1, a range far away: out is the float32 normal itself
        sn.apply(raw, out, -100.0, 100.0, 1.0, seed)
        tail = np.abs(out[np.abs(out) > r]).astype(np.float64)
        beyond += [tail.size] + [int(np.sum(tail > k)) for k in cuts]
    n = 4 * raw.size
    expected = n * 2 * (1 - phi(r))
    assert abs(beyond[0] - expected) < 5 * math.sqrt(expected)
    for k, count in zip(cuts, beyond[1:], strict=True):
        p = (1 - phi(k)) / (1 - phi(r))  # 0.82, 0.55, 0.25, 0.067, 0.016
        assert abs(count / beyond[0] - p) < 5 * math.sqrt(p * (1 - p) / beyond[0]), k


def test_noise_kolmogorov_smirnov_and_symmetry(draws: F64) -> None:
    sample = np.sort(draws[:200_000])
    m = sample.size
    cdf = np.array([phi(float(x)) for x in sample])
    d = max(float(np.max(np.arange(1, m + 1) / m - cdf)), float(np.max(cdf - np.arange(m) / m)))
    assert d < 0.005  # ~1.6 / sqrt(m): the 1% critical value is 1.63 / sqrt(m)
    assert abs(np.mean(draws > 0) - 0.5) < 5 * 0.5 / math.sqrt(draws.size)


def test_noise_chi_square_on_equiprobable_bins(draws: F64) -> None:
    """Finer than KS: a ziggurat layer or wedge of the wrong size shows in its band of bins."""
    bins = 400
    edges = []
    for k in range(1, bins):  # the normal quantiles k / bins, by bisection on erf
        lo, hi = -10.0, 10.0
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if phi(mid) < k / bins else (lo, mid)
        edges.append(0.5 * (lo + hi))
    counts = np.bincount(np.searchsorted(np.array(edges), draws), minlength=bins)
    expected = draws.size / bins
    chi2 = float(np.sum((counts - expected) ** 2) / expected)
    df = bins - 1
    assert chi2 < df + 6 * math.sqrt(2 * df), chi2
    assert np.max(np.abs(counts - expected)) < 5.5 * math.sqrt(expected)


def test_noise_has_no_serial_correlation(draws: F64) -> None:
    n = draws.size - 1
    for lag in (1, 2, 3, 4):  # lag 1 pairs the two halves of one 64-bit output
        corr = float(np.corrcoef(draws[:-lag], draws[lag:])[0, 1])
        assert abs(corr) < 5 / math.sqrt(n), lag


# ------------------------------------------------------------------------------- determinism


def test_same_seed_same_bytes_other_seed_other_noise() -> None:
    raw = mixed_scans(np.random.default_rng(4), (100, 360))
    a, b = apply(raw, 0.01, 99), apply(raw, 0.01, 99)
    assert a.tobytes() == b.tobytes()
    hit = raw < np.float32(RMAX)
    for other in (98, 0, 2**64 - 1, 2**63):
        c = apply(raw, 0.01, other)
        assert np.array_equal(c[~hit], a[~hit])
        assert np.mean(c[hit] != a[hit]) > 0.95, other
    assert not np.array_equal(apply(raw, 0.01, 0), apply(raw, 0.01, 2**64 - 1))


def test_in_place_equals_out_of_place_and_shape_does_not_matter() -> None:
    raw = mixed_scans(np.random.default_rng(5), (37, 361))
    want = apply(raw, 0.02, 3)
    inplace = raw.copy()
    sn.apply(inplace, inplace, RMIN, RMAX, 0.02, 3)
    assert inplace.tobytes() == want.tobytes()
    assert apply(raw.reshape(-1), 0.02, 3).tobytes() == want.tobytes()
    assert apply(raw.reshape(361, 37), 0.02, 3).tobytes() == want.tobytes()


@pytest.mark.parametrize("shift", [1, -1, 3, -250, 300])
def test_overlapping_out_acts_as_if_raw_were_copied_first(shift: int) -> None:
    n = 1000
    buf = mixed_scans(np.random.default_rng(6), (n + abs(shift),))
    raw = buf[max(0, -shift) : max(0, -shift) + n]
    out = buf[max(0, shift) : max(0, shift) + n]
    want = apply(raw.copy(), 0.02, 8)
    sn.apply(raw, out, RMIN, RMAX, 0.02, 8)
    assert out.tobytes() == want.tobytes()


def test_the_kth_hit_gets_the_kth_normal_whatever_the_layout() -> None:
    rng = np.random.default_rng(7)
    hits = 3000
    streams = []
    for fraction in (1.0, 0.5, 0.1, 0.003):  # contiguous, mixed, sparse, one hit per chunk or less
        n = int(hits / fraction)
        raw = np.full(n, np.inf, dtype=np.float32)
        raw[np.sort(rng.choice(n, hits, replace=False))] = 2.0
        out = apply(raw, 0.05, 12)
        streams.append(out[raw == 2.0])
        # and the first m beams give the first m outputs (however far ahead normals were made)
        for m in (1, 255, 256, 257, 511, 777, n - 1):
            assert apply(raw[:m], 0.05, 12).tobytes() == out[:m].tobytes()
    for s in streams[1:]:
        assert s.tobytes() == streams[0].tobytes()


def test_threads_get_the_same_results_as_one() -> None:
    raws = [mixed_scans(np.random.default_rng(10 + k), (50, 360)) for k in range(8)]
    want = [apply(raw, 0.01, k) for k, raw in enumerate(raws)]

    def work(k: int) -> bytes:
        out = np.empty_like(raws[k])
        for _ in range(20):
            sn.apply(raws[k], out, RMIN, RMAX, 0.01, k)
        return out.tobytes()

    with ThreadPoolExecutor(4) as pool:
        got = list(pool.map(work, range(8)))
    assert got == [w.tobytes() for w in want]


# ------------------------------------------------------------------------------- bad input

GOOD = np.ones(8, dtype=np.float32)


def read_only() -> F32:
    a = np.ones(8, dtype=np.float32)
    a.flags.writeable = False
    return a


BAD_BUFFERS: list[tuple[Callable[[], tuple[Any, Any]], type[Exception], str]] = [
    (lambda: (np.ones(8), np.ones(8, dtype=np.float32)), TypeError, "raw must hold float32"),
    (lambda: (GOOD, np.ones(8)), TypeError, "out must hold float32"),
    (lambda: (np.ones(8, dtype=np.int32), GOOD.copy()), TypeError, "raw must hold float32"),
    (lambda: (np.ones(8, dtype=">f4"), GOOD.copy()), TypeError, "raw must hold float32"),
    (lambda: (np.ones(16, dtype=np.float32)[::2], GOOD.copy()), ValueError, "raw must be a C-contiguous"),
    (lambda: (GOOD, np.ones(16, dtype=np.float32)[::2]), ValueError, "out must be a C-contiguous"),
    (lambda: (np.ones((4, 2), dtype=np.float32, order="F"), GOOD.copy()), ValueError, "C-contiguous"),
    (lambda: (GOOD, read_only()), ValueError, "writable"),
    (lambda: (GOOD, bytes(32)), ValueError, "writable"),
    (lambda: (GOOD, np.ones(7, dtype=np.float32)), ValueError, "out holds 7 items, raw 8"),
    (lambda: (np.ones(9, dtype=np.float32), GOOD.copy()), ValueError, "out holds 8 items, raw 9"),
    (lambda: ([1.0] * 8, GOOD.copy()), TypeError, "raw must be a float32 buffer"),
    (lambda: (GOOD, None), TypeError, "out must be a float32 buffer"),
    (lambda: ("abcdefgh", GOOD.copy()), TypeError, "raw must be a float32 buffer"),
]


@pytest.mark.parametrize(("make", "error", "message"), BAD_BUFFERS)
def test_bad_buffers_raise(make: Callable[[], tuple[Any, Any]], error: type[Exception], message: str) -> None:
    raw, out = make()
    before = bytes(out) if isinstance(out, np.ndarray) else None
    with pytest.raises(error, match=message):
        sn.apply(raw, out, RMIN, RMAX, 0.01, 1)
    if before is not None:
        assert bytes(out) == before  # nothing written


BAD_NUMBERS: list[tuple[tuple[Any, Any, Any, Any], type[Exception], str]] = [
    ((RMIN, RMAX, float("nan"), 1), ValueError, "stddev"),
    ((RMIN, RMAX, -0.01, 1), ValueError, "stddev"),
    ((RMIN, RMAX, float("inf"), 1), ValueError, "stddev"),
    ((RMIN, RMAX, 1e39, 1), ValueError, "stddev"),  # +inf as float32
    ((float("nan"), RMAX, 0.01, 1), ValueError, "NaN"),
    ((RMIN, float("nan"), 0.01, 1), ValueError, "NaN"),
    ((RMAX, RMIN, 0.01, 1), ValueError, "must not exceed"),
    ((RMIN, RMAX, 0.01, -1), OverflowError, "seed"),
    ((RMIN, RMAX, 0.01, 2**64), OverflowError, "seed"),
    ((RMIN, RMAX, 0.01, 1.0), TypeError, "seed must be an int"),
    ((RMIN, RMAX, 0.01, "1"), TypeError, "seed must be an int"),
    ((RMIN, RMAX, 0.01, None), TypeError, "seed must be an int"),
    (("0.1", RMAX, 0.01, 1), TypeError, "range_min must be a real number"),
    ((RMIN, None, 0.01, 1), TypeError, "range_max must be a real number"),
    ((RMIN, RMAX, [0.01], 1), TypeError, "stddev must be a real number"),
    ((RMIN, 10**400, 0.01, 1), OverflowError, "too large"),
]


@pytest.mark.parametrize(("numbers", "error", "message"), BAD_NUMBERS)
def test_bad_numbers_raise(numbers: tuple[Any, Any, Any, Any], error: type[Exception], message: str) -> None:
    out = GOOD.copy() * 2
    with pytest.raises(error, match=message):
        sn.apply(GOOD, out, *numbers)
    assert np.all(out == 2)


def test_calling_conventions() -> None:
    out = np.empty_like(GOOD)
    sn.apply(raw=GOOD, out=out, range_min=RMIN, range_max=RMAX, stddev=0.0, seed=0)
    assert np.array_equal(out, GOOD)
    # numpy scalars, ints and bools are numbers; a numpy integer is a seed
    sn.apply(GOOD, out, np.float32(RMIN), np.float64(RMAX), np.float32(0.01), np.uint64(2**64 - 1))
    sn.apply(GOOD, out, 0, 4, 1, True)
    with pytest.raises(TypeError):
        sn.apply(GOOD, out, RMIN, RMAX, 0.01)
    with pytest.raises(TypeError):
        sn.apply(GOOD, out, RMIN, RMAX, 0.01, 1, 2)
    with pytest.raises(TypeError):
        sn.apply(GOOD, out, RMIN, RMAX, 0.01, seed=1, sed=2)
