"""XXH3-128 (seed 0, the default secret) in pure Python: the hash rmw_zenoh turns a liveliness
token into an entity's 16-byte GID with.

Written from the xxHash specification (Yann Collet, ``doc/xxhash_spec.md`` of
github.com/Cyan4973/xxHash, XXH3 section): every input-length branch of the 128-bit variant
(0, 1-3, 4-8, 9-16, 17-128, 129-240 bytes, and the striped long hash beyond). Speed does not
matter here (a few tokens per daemon start); the result is checked against vectors of the
reference C implementation in ``tests/adapters/test_xxh3.py``.
"""

from __future__ import annotations

_M64 = (1 << 64) - 1
_M32 = (1 << 32) - 1

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

#: XXH3's default 192-byte secret (the specification's ``kSecret``)
SECRET = bytes.fromhex(
    "b8fe6c3923a44bbe7c01812cf721ad1cded46de9839097db7240a4a4b7b3671f"
    "cb79e64eccc0e578825ad07dccff7221b8084674f743248ee03590e6813a264c"
    "3c2852bb91c300cb88d0658b1b532ea371644897a20df94e3819ef46a9deacd8"
    "a8fa763fe39c343ff9dcbbc7c70b4f1d8a51e04bcdb45931c89f7ec9d9787364"
    "eac5ac8334d3ebc3c581a0fffa1363eb170ddd51b7f0da49d316552629d4689e"
    "2b16be587d47a1fc8ff8b8d17ad031ce45cb3a8f95160428afd7fbcabb4b407e")
_STRIPE = 64
_SECRET_MIN = 136


def _r64(b: bytes, i: int) -> int:
    return int.from_bytes(b[i:i + 8], "little")


def _r32(b: bytes, i: int) -> int:
    return int.from_bytes(b[i:i + 4], "little")


def _mul128(a: int, b: int) -> tuple[int, int]:
    """The full 128-bit product of two 64-bit numbers: (low, high)."""
    p = a * b
    return p & _M64, p >> 64


def _fold(a: int, b: int) -> int:
    lo, hi = _mul128(a, b)
    return lo ^ hi


def _avalanche(h: int) -> int:
    h ^= h >> 37
    h = (h * PRIME_MX1) & _M64
    return h ^ (h >> 32)


def _xxh64_avalanche(h: int) -> int:
    h ^= h >> 33
    h = (h * PRIME64_2) & _M64
    h ^= h >> 29
    h = (h * PRIME64_3) & _M64
    return h ^ (h >> 32)


def _swap64(x: int) -> int:
    return int.from_bytes(x.to_bytes(8, "little"), "big")


def _swap32(x: int) -> int:
    return int.from_bytes(x.to_bytes(4, "little"), "big")


def _rotl32(x: int, r: int) -> int:
    return ((x << r) | (x >> (32 - r))) & _M32


def _mix16(data: bytes, i: int, s: int) -> int:
    return _fold(_r64(data, i) ^ _r64(SECRET, s), _r64(data, i + 8) ^ _r64(SECRET, s + 8))


def _mix32(acc: tuple[int, int], data: bytes, i1: int, i2: int, s: int) -> tuple[int, int]:
    lo, hi = acc
    lo = (lo + _mix16(data, i1, s)) & _M64
    lo ^= (_r64(data, i2) + _r64(data, i2 + 8)) & _M64
    hi = (hi + _mix16(data, i2, s + 16)) & _M64
    hi ^= (_r64(data, i1) + _r64(data, i1 + 8)) & _M64
    return lo, hi


def _finish_mid(acc: tuple[int, int], n: int) -> tuple[int, int]:
    lo, hi = acc
    low = _avalanche((lo + hi) & _M64)
    high = (lo * PRIME64_1 + hi * PRIME64_4 + n * PRIME64_2) & _M64
    return low, (-_avalanche(high)) & _M64


def _len_0(data: bytes) -> tuple[int, int]:
    return (_xxh64_avalanche(_r64(SECRET, 64) ^ _r64(SECRET, 72)),
            _xxh64_avalanche(_r64(SECRET, 80) ^ _r64(SECRET, 88)))


def _len_1to3(data: bytes) -> tuple[int, int]:
    n = len(data)
    combined_lo = (data[0] << 16) | (data[n >> 1] << 24) | data[n - 1] | (n << 8)
    combined_hi = _rotl32(_swap32(combined_lo), 13)
    flip_lo = _r32(SECRET, 0) ^ _r32(SECRET, 4)
    flip_hi = _r32(SECRET, 8) ^ _r32(SECRET, 12)
    return _xxh64_avalanche(combined_lo ^ flip_lo), _xxh64_avalanche(combined_hi ^ flip_hi)


def _len_4to8(data: bytes) -> tuple[int, int]:
    n = len(data)
    value = _r32(data, 0) + (_r32(data, n - 4) << 32)
    keyed = value ^ (_r64(SECRET, 16) ^ _r64(SECRET, 24))
    lo, hi = _mul128(keyed, (PRIME64_1 + (n << 2)) & _M64)
    hi = (hi + (lo << 1)) & _M64
    lo ^= hi >> 3
    lo ^= lo >> 35
    lo = (lo * PRIME_MX2) & _M64
    lo ^= lo >> 28
    return lo, _avalanche(hi)


def _len_9to16(data: bytes) -> tuple[int, int]:
    n = len(data)
    flip_lo = _r64(SECRET, 32) ^ _r64(SECRET, 40)
    flip_hi = _r64(SECRET, 48) ^ _r64(SECRET, 56)
    first, last = _r64(data, 0), _r64(data, n - 8)
    lo, hi = _mul128(first ^ last ^ flip_lo, PRIME64_1)
    lo = (lo + ((n - 1) << 54)) & _M64
    last ^= flip_hi
    hi = (hi + last + (last & _M32) * (PRIME32_2 - 1)) & _M64
    lo ^= _swap64(hi)
    h_lo, h_hi = _mul128(lo, PRIME64_2)
    h_hi = (h_hi + hi * PRIME64_2) & _M64
    return _avalanche(h_lo), _avalanche(h_hi)


def _len_17to128(data: bytes) -> tuple[int, int]:
    n = len(data)
    acc = ((n * PRIME64_1) & _M64, 0)
    if n > 32:
        if n > 64:
            if n > 96:
                acc = _mix32(acc, data, 48, n - 64, 96)
            acc = _mix32(acc, data, 32, n - 48, 64)
        acc = _mix32(acc, data, 16, n - 32, 32)
    acc = _mix32(acc, data, 0, n - 16, 0)
    return _finish_mid(acc, n)


def _len_129to240(data: bytes) -> tuple[int, int]:
    n = len(data)
    acc = ((n * PRIME64_1) & _M64, 0)
    for i in range(4):
        acc = _mix32(acc, data, 32 * i, 32 * i + 16, 32 * i)
    acc = (_avalanche(acc[0]), _avalanche(acc[1]))
    for i in range(4, n // 32):
        acc = _mix32(acc, data, 32 * i, 32 * i + 16, 3 + 32 * (i - 4))
    # the last 32 bytes, read the other way round, with the secret's "last" offset
    acc = _mix32(acc, data, n - 16, n - 32, _SECRET_MIN - 17 - 16)
    return _finish_mid(acc, n)


def _accumulate(acc: list[int], data: bytes, i: int, s: int) -> None:
    """One 64-byte stripe at ``data[i:]`` into the eight lanes, with the secret at ``s``."""
    for lane in range(8):
        value = _r64(data, i + 8 * lane)
        key = value ^ _r64(SECRET, s + 8 * lane)
        acc[lane ^ 1] = (acc[lane ^ 1] + value) & _M64
        acc[lane] = (acc[lane] + (key & _M32) * (key >> 32)) & _M64


def _scramble(acc: list[int]) -> None:
    s = len(SECRET) - _STRIPE
    for lane in range(8):
        a = acc[lane]
        a ^= a >> 47
        a ^= _r64(SECRET, s + 8 * lane)
        acc[lane] = (a * PRIME32_1) & _M64


def _merge(acc: list[int], s: int, start: int) -> int:
    total = start
    for i in range(4):
        total += _fold(acc[2 * i] ^ _r64(SECRET, s + 16 * i),
                       acc[2 * i + 1] ^ _r64(SECRET, s + 16 * i + 8))
    return _avalanche(total & _M64)


def _long(data: bytes) -> tuple[int, int]:
    n = len(data)
    acc = [PRIME32_3, PRIME64_1, PRIME64_2, PRIME64_3, PRIME64_4, PRIME32_2, PRIME64_5,
           PRIME32_1]
    per_block = (len(SECRET) - _STRIPE) // 8           # stripes per block, 8 secret bytes each
    block = _STRIPE * per_block
    blocks = (n - 1) // block
    for b in range(blocks):
        for k in range(per_block):
            _accumulate(acc, data, b * block + k * _STRIPE, 8 * k)
        _scramble(acc)
    for k in range(((n - 1) - block * blocks) // _STRIPE):
        _accumulate(acc, data, blocks * block + k * _STRIPE, 8 * k)
    _accumulate(acc, data, n - _STRIPE, len(SECRET) - _STRIPE - 7)
    return (_merge(acc, 11, (n * PRIME64_1) & _M64),
            _merge(acc, len(SECRET) - 64 - 11, ~(n * PRIME64_2) & _M64))


def xxh3_128(data: bytes) -> tuple[int, int]:
    """XXH3-128 of ``data`` (seed 0): ``(low64, high64)``."""
    data = bytes(data)
    n = len(data)
    if n == 0:
        return _len_0(data)
    if n <= 3:
        return _len_1to3(data)
    if n <= 8:
        return _len_4to8(data)
    if n <= 16:
        return _len_9to16(data)
    if n <= 128:
        return _len_17to128(data)
    if n <= 240:
        return _len_129to240(data)
    return _long(data)


def xxh3_128_hex(data: bytes) -> str:
    """The canonical (big-endian, high half first) hex form, as ``xxhsum -H2`` prints it."""
    lo, hi = xxh3_128(data)
    return f"{hi:016x}{lo:016x}"
