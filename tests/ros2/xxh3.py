"""XXH3-128 with the default seed (0) and secret, in plain Python, for the stand-in's GIDs.

rmw_zenoh makes an entity's GID from its liveliness token: ``simplified_XXH3_128bits`` of the
token's text, the low 64-bit half then the high half, each little-endian
(``src/detail/liveliness_utils.cpp``, ``Entity::Entity``). The daemon computes it with the
``xxhash`` library; the stand-in computes it here, written from the algorithm's specification
(xxHash's ``doc/xxhash_spec.md`` 0.2.0, "XXH3 Algorithm Description", sections for small,
medium and large inputs) rather than from any implementation, and checked against the test
vectors that xxHash's own sanity test publishes (``tests/ros2/test_ros2_gid.py``). Slow (pure
Python), which a test does not mind: a token is a few hundred bytes.
"""

from __future__ import annotations

M64 = (1 << 64) - 1

PRIME32_1 = 0x9E3779B1
PRIME32_2 = 0x85EBCA77
PRIME32_3 = 0xC2B2AE3D
PRIME64_1 = 0x9E3779B185EBCA87
PRIME64_2 = 0xC2B2AE3D27D4EB4F
PRIME64_3 = 0x165667B19E3779F9
PRIME64_4 = 0x85EBCA77C2B2AE63
PRIME64_5 = 0x27D4EB2F165667C5
PRIME_MX1 = 0x165667919E3779F9
PRIME_MX2 = 0x9FB21C651E98DF25

#: the specification's default secret (192 bytes)
SECRET = bytes.fromhex(
    "b8fe6c3923a44bbe7c01812cf721ad1cded46de9839097db7240a4a4b7b3671f"
    "cb79e64eccc0e578825ad07dccff7221b8084674f743248ee03590e6813a264c"
    "3c2852bb91c300cb88d0658b1b532ea371644897a20df94e3819ef46a9deacd8"
    "a8fa763fe39c343ff9dcbbc7c70b4f1d8a51e04bcdb45931c89f7ec9d9787364"
    "eac5ac8334d3ebc3c581a0fffa1363eb170ddd51b7f0da49d316552629d4689e"
    "2b16be587d47a1fc8ff8b8d17ad031ce45cb3a8f95160428afd7fbcabb4b407e"
)
STRIPE = 64
STRIPES_PER_BLOCK = (len(SECRET) - STRIPE) // 8  # 16
BLOCK = STRIPE * STRIPES_PER_BLOCK  # 1024


def _u32(b: bytes, i: int) -> int:
    return int.from_bytes(b[i : i + 4], "little")


def _u64(b: bytes, i: int) -> int:
    return int.from_bytes(b[i : i + 8], "little")


def _bswap32(x: int) -> int:
    return int.from_bytes(x.to_bytes(4, "little"), "big")


def _bswap64(x: int) -> int:
    return int.from_bytes(x.to_bytes(8, "little"), "big")


def _rotl32(x: int, r: int) -> int:
    return ((x << r) | (x >> (32 - r))) & 0xFFFFFFFF


def _avalanche(x: int) -> int:
    x ^= x >> 37
    x = (x * PRIME_MX1) & M64
    return x ^ (x >> 32)


def _avalanche_xxh64(x: int) -> int:
    x ^= x >> 33
    x = (x * PRIME64_2) & M64
    x ^= x >> 29
    x = (x * PRIME64_3) & M64
    return x ^ (x >> 32)


def xxh3_128(data: bytes) -> tuple[int, int]:
    """(low64, high64) of XXH3-128 with seed 0."""
    n = len(data)
    if n == 0:
        return (_avalanche_xxh64(_u64(SECRET, 64) ^ _u64(SECRET, 72)),
                _avalanche_xxh64(_u64(SECRET, 80) ^ _u64(SECRET, 88)))  # fmt: skip
    if n <= 3:
        return _1to3(data)
    if n <= 8:
        return _4to8(data)
    if n <= 16:
        return _9to16(data)
    if n <= 240:
        return _17to240(data)
    return _large(data)


def gid(token: str) -> bytes:
    """rmw_zenoh's GID of an entity: the token's XXH3-128, low half then high half, little-endian."""
    low, high = xxh3_128(token.encode())
    return low.to_bytes(8, "little") + high.to_bytes(8, "little")


# -- small inputs ---------------------------------------------------------------------------------


def _1to3(data: bytes) -> tuple[int, int]:
    n = len(data)
    combined = data[-1] | (n << 8) | (data[0] << 16) | (data[n >> 1] << 24)
    low = (_u32(SECRET, 0) ^ _u32(SECRET, 4)) ^ combined
    high = ((_u32(SECRET, 8) ^ _u32(SECRET, 12)) ^ _rotl32(_bswap32(combined), 13)) & M64
    return _avalanche_xxh64(low), _avalanche_xxh64(high)


def _4to8(data: bytes) -> tuple[int, int]:
    n = len(data)
    combined = _u32(data, 0) | (_u32(data, n - 4) << 32)
    value = (_u64(SECRET, 16) ^ _u64(SECRET, 24)) ^ combined  # the modified seed is 0 for seed 0
    product = value * ((PRIME64_1 + (n << 2)) & M64)
    high, low = product >> 64, product & M64
    high = (high + (low << 1)) & M64
    low ^= high >> 3
    low ^= low >> 35
    low = (low * PRIME_MX2) & M64
    low ^= low >> 28
    return low, _avalanche(high)


def _9to16(data: bytes) -> tuple[int, int]:
    n = len(data)
    first, last = _u64(data, 0), _u64(data, n - 8)
    val1 = (_u64(SECRET, 32) ^ _u64(SECRET, 40)) ^ first ^ last
    val2 = (_u64(SECRET, 48) ^ _u64(SECRET, 56)) ^ last
    product = val1 * PRIME64_1
    low = ((product & M64) + ((n - 1) << 54)) & M64
    high = ((product >> 64) + (val2 & 0xFFFFFFFF00000000) + (val2 & 0xFFFFFFFF) * PRIME32_2) & M64
    low ^= _bswap64(high)
    product = low * PRIME64_2
    low = product & M64
    high = ((product >> 64) + high * PRIME64_2) & M64
    return _avalanche(low), _avalanche(high)


# -- medium inputs (17 to 240 bytes) --------------------------------------------------------------


def _mix_step(data: bytes, offset: int, secret_offset: int) -> int:
    product = (_u64(data, offset) ^ _u64(SECRET, secret_offset)) * (
        _u64(data, offset + 8) ^ _u64(SECRET, secret_offset + 8)
    )
    return (product & M64) ^ (product >> 64)


def _mix_two_chunks(acc: list[int], data: bytes, first: int, second: int, secret_offset: int) -> None:
    acc[0] = (acc[0] + _mix_step(data, first, secret_offset)) & M64
    acc[1] = (acc[1] + _mix_step(data, second, secret_offset + 16)) & M64
    acc[0] ^= (_u64(data, second) + _u64(data, second + 8)) & M64
    acc[1] ^= (_u64(data, first) + _u64(data, first + 8)) & M64


def _17to240(data: bytes) -> tuple[int, int]:
    n = len(data)
    acc = [(n * PRIME64_1) & M64, 0]
    if n <= 128:
        for i in reversed(range(((n - 1) >> 5) + 1)):
            _mix_two_chunks(acc, data, i * 16, n - i * 16 - 16, i * 32)
    else:
        for i in range(4):
            _mix_two_chunks(acc, data, i * 32, i * 32 + 16, i * 32)
        acc = [_avalanche(acc[0]), _avalanche(acc[1])]
        for i in range(4, n >> 5):
            _mix_two_chunks(acc, data, i * 32, i * 32 + 16, (i - 4) * 32 + 3)
        _mix_two_chunks(acc, data, n - 16, n - 32, 103)  # the halves swapped (and the seed negated: 0)
    low = (acc[0] + acc[1]) & M64
    high = (acc[0] * PRIME64_1 + acc[1] * PRIME64_4 + n * PRIME64_2) & M64
    return _avalanche(low), (-_avalanche(high)) & M64


# -- large inputs (more than 240 bytes) -----------------------------------------------------------


def _accumulate(acc: list[int], data: bytes, offset: int, secret_offset: int) -> None:
    for i in range(8):
        value = _u64(data, offset + 8 * i)
        key = value ^ _u64(SECRET, secret_offset + 8 * i)
        acc[i ^ 1] = (acc[i ^ 1] + value) & M64
        acc[i] = (acc[i] + (key & 0xFFFFFFFF) * (key >> 32)) & M64


def _scramble(acc: list[int]) -> None:
    for i in range(8):
        a = acc[i] ^ (acc[i] >> 47)
        a ^= _u64(SECRET, len(SECRET) - STRIPE + 8 * i)
        acc[i] = (a * PRIME32_1) & M64


def _merge(acc: list[int], start: int, secret_offset: int) -> int:
    result = start
    for i in range(4):
        product = (acc[2 * i] ^ _u64(SECRET, secret_offset + 16 * i)) * (
            acc[2 * i + 1] ^ _u64(SECRET, secret_offset + 16 * i + 8)
        )
        result = (result + ((product & M64) ^ (product >> 64))) & M64
    return _avalanche(result)


def _large(data: bytes) -> tuple[int, int]:
    n = len(data)
    acc = [PRIME32_3, PRIME64_1, PRIME64_2, PRIME64_3, PRIME64_4, PRIME32_2, PRIME64_5, PRIME32_1]
    blocks = (n - 1) // BLOCK  # the last block, full or not, is left to the end
    for b in range(blocks):
        for s in range(STRIPES_PER_BLOCK):
            _accumulate(acc, data, b * BLOCK + s * STRIPE, s * 8)
        _scramble(acc)
    start = blocks * BLOCK
    for s in range((n - start - 1) // STRIPE):
        _accumulate(acc, data, start + s * STRIPE, s * 8)
    _accumulate(acc, data, n - STRIPE, len(SECRET) - 71)  # the last 64 bytes, which may overlap
    return _merge(acc, (n * PRIME64_1) & M64, 11), _merge(acc, ~(n * PRIME64_2) & M64, len(SECRET) - 75)
