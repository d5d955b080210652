"""The wire an isolated env's worker answers on (``hub_envs.isolation.wire``): what envs return comes back
exactly; what a hostile worker could forge is refused before anything is built."""

from __future__ import annotations

import collections
import math

import gymnasium as gym
import msgpack
import numpy as np
import pytest

from hub_envs import errors
from hub_envs.isolation import wire
from hub_envs.isolation.wire import ARRAY, DTYPE, OBJECT_ARRAY, RANDOM, SCALAR, SPACE, TUPLE, TYPE, Unsendable, decode, encode

S = gym.spaces


def _same_array(a: np.ndarray, b: np.ndarray) -> bool:
    if type(b) is not np.ndarray or a.dtype != b.dtype or a.shape != b.shape or not b.flags.writeable:
        return False
    if a.dtype == object:
        return all(type(x) is type(y) for x, y in zip(a.ravel(), b.ravel(), strict=True)) and repr(a) == repr(b)
    return a.tobytes() == b.tobytes() and (a.ndim < 2 or a.flags.f_contiguous == b.flags.f_contiguous or not a.flags.c_contiguous)


def test_values_envs_return_come_back_exactly():
    """Types, dtypes, byte order, shapes, memory order, key order and values -- the same as the env returned."""
    plain = {
        "q": collections.deque([1, 2], maxlen=5),
        "d": collections.defaultdict(list, a=[1]),
        "types": [list, (tuple, set), np.float32, np.dtypes.Float32DType],
        frozenset({1, (2, "x")}): {b"bytes", None},
        "r": range(10**12),
        "big": 2**200,
        "negative": -(2**70),
        "c": 1 + 2j,
        "sl": slice(1, None, "a"),
        "od": collections.OrderedDict(b=1, a=2),
        3: [0.1, float("inf"), -0.0, True],
        (1, 2): "tuple key",
    }
    back = decode(encode(plain))
    assert list(back) == list(plain) and back == plain  # (a set's repr may list its items in another order)
    assert str(back[3][2]) == "-0.0" and math.isnan(decode(encode(float("nan"))))
    for k in plain:
        assert type(back[k]) is type(plain[k])
    assert back["d"].default_factory is list and back["q"].maxlen == 5 and back["types"][2] is np.float32
    arrays = [
        np.arange(6.0)[::2],
        np.asfortranarray(np.arange(6, dtype=">i2").reshape(2, 3)),
        np.zeros((0, 3), np.uint8),
        np.array(3.5),
        np.array(["ab", "c"]),
        np.zeros(2, dtype=[("x", "<f4"), ("y", "<i8", (2,))]),
        np.zeros(2, dtype=np.dtype({"names": ["a", "b"], "formats": ["u1", "<f8"], "offsets": [0, 8], "itemsize": 24})),
        np.array([None, {"a": 1}, np.zeros(2)], dtype=object),
        np.array(["2020-01-01"], dtype="datetime64[s]"),
    ]
    for a in arrays:
        assert _same_array(a, decode(encode(a))), a
    for x in (
        np.float32(1.5),
        np.int64(3),
        np.bool_(True),
        np.str_("hé"),
        np.float64(2.0),
        np.datetime64("2020-01-01"),
        np.dtype(">i2"),
    ):
        b = decode(encode(x))
        assert type(b) is type(x) and b == x
    for make in (np.random.PCG64, np.random.PCG64DXSM, np.random.MT19937, np.random.Philox, np.random.SFC64):
        rng = np.random.Generator(make(7))
        rng.random(3)
        b = decode(encode(rng))
        assert type(b.bit_generator) is make and b.bit_generator.seed_seq.state == rng.bit_generator.seed_seq.state
        assert b.random(5).tolist() == rng.random(5).tolist() and b.integers(0, 2**40) == rng.integers(0, 2**40)
    legacy = np.random.RandomState(4)
    assert decode(encode(legacy)).random_sample() == legacy.random_sample()


@pytest.mark.parametrize(
    "space",
    [
        S.Box(0.0, 1.0, (2,)),
        S.Box(np.array([-1, 0], np.int32), np.array([3, 4], np.int32), dtype=np.int32),
        S.Box(-np.inf, np.inf, (2, 3), np.float64),
        S.Discrete(3, start=1),
        S.MultiDiscrete([2, 3]),
        S.MultiBinary([2, 3]),
        S.Text(5, min_length=2, charset="cab"),
        S.Dict({"b": S.Box(0, 1, (2,)), "a": S.Discrete(2)}),
        S.Dict([("z", S.Discrete(2)), ("a", S.Discrete(3))]),  # an order that is not sorted
        S.Tuple([S.Discrete(2), S.Box(-1, 1, (1,))]),
        S.Sequence(S.Discrete(3), stack=True),
        S.Graph(S.Box(0, 1, (2,)), S.Discrete(3)),
        S.OneOf([S.Discrete(2), S.Box(0, 1, (1,))]),
    ],
    ids=lambda s: type(s).__name__,
)
def test_gymnasium_spaces_come_back_equal_in_order_and_with_their_random_state(space):
    assert decode(encode(space)).np_random is not None  # unseeded: a fresh generator, as gymnasium makes one
    space.seed(3)
    space.sample()
    back = decode(encode(space))
    assert type(back) is type(space) and back == space and repr(back) == repr(space)
    if isinstance(space, S.Dict):
        assert list(back.spaces) == list(space.spaces)
    for _ in range(3):
        assert repr(back.sample()) == repr(space.sample())


def test_what_the_wire_cannot_carry_is_named_where_it_is():
    for value, said in (
        ({"f": print}, r"info\['f'\] is of type builtin_function_or_method"),
        ({"m": [np.ma.masked_array([1])]}, r"info\['m'\]\[0\] is of type numpy.ma.MaskedArray"),
        ({"e": [collections.defaultdict(lambda: 0)]}, r"info\['e'\]\[0\] is a defaultdict whose factory is a function"),
        ({"t": object}, r"info\['t'\] is the type builtins.object"),
        ({"s": type("Custom", (S.Discrete,), {})(3)}, r"info\['s'\] is a space of class"),
        ({"o": np.zeros(1, dtype=[("a", "O")])}, r"info\['o'\] is a numpy array of dtype .* Python objects"),
    ):
        with pytest.raises(Unsendable, match=said):
            encode(value, "info")


def _ext(code: int, *items) -> msgpack.ExtType:
    return msgpack.ExtType(code, msgpack.packb(list(items) if len(items) != 1 else items[0], default=_nested))


def _nested(x):  # forged records as they are, honest values (a state's arrays) as the wire encodes them
    return x if isinstance(x, msgpack.ExtType) else wire._default(x)


def _array(desc, shape, fortran, data: bytes) -> msgpack.ExtType:
    head = msgpack.packb([desc, shape, fortran])
    return msgpack.ExtType(ARRAY, len(head).to_bytes(4, "little") + head + data)


def _forged(value) -> bytes:
    return msgpack.packb(value, default=_nested)


def test_records_asking_for_more_than_they_carry_or_for_code_are_refused_before_anything_is_built():
    """A hostile worker's answers (what a red-team pass of the old pickle decoder found, in this wire's terms): each
    an IsolationError decided from the record itself, in a few microseconds, with nothing allocated."""
    pcg = np.random.PCG64(1).state
    mt = np.random.MT19937(1).state
    philox = np.random.Philox(1).state
    seq = {"entropy": 1, "spawn_key": [], "pool_size": 10**9, "n_children_spawned": 0}
    big = 2**31
    for value, said in (
        (_array("|u1", [10**11], False, b""), "asks for an array of 100,000,000,000 bytes"),
        (_array("|V0", [10**12], False, b""), "items of an empty dtype"),
        (_array("|O", [2], False, b"A" * 16), "Python objects read from raw bytes"),
        (
            _array({"names": ["a"], "formats": ["|O"], "offsets": [0], "itemsize": 8, "aligned": False}, [1], False, b"A" * 8),
            "Python objects",
        ),
        (_array([["<f8", [big, big]]], [1], False, b""), "dtype"),
        (msgpack.ExtType(ARRAY, (2**31).to_bytes(4, "little") + b"\x93"), "header is longer than the record"),
        (_ext(OBJECT_ARRAY, [10**9], [1]), "object array of shape"),
        (msgpack.ExtType(SCALAR, b"\x0bV1000000000"), "scalar of 1000000000 bytes from 0 bytes"),
        (msgpack.ExtType(SCALAR, b"\x01O" + bytes(8)), "Python objects"),
        (_ext(TYPE, "os.system"), "names a type"),
        (msgpack.ExtType(TYPE, b"posix.system"), "off the wire's list"),
        (msgpack.ExtType(99, b""), "unknown kind 99"),
        (_ext(RANDOM, "Generator", "MT19937", {**mt, "state": {**mt["state"], "pos": 10**8}}, None), "MT19937 position"),
        (_ext(RANDOM, "Generator", "Philox", {**philox, "buffer_pos": 5}, None), "Philox buffer position"),
        (_ext(RANDOM, "Generator", "PCG64", pcg, seq), "seed pool size"),
        (_ext(RANDOM, "Generator", "numpy.random._generator", pcg, None), "random generator"),
        (_ext(SPACE, "Box", [0.0, 1.0], None), "bounds are not two arrays"),
        (_ext(SPACE, "MultiBinary", [[10**20]], None), "array dimension"),
        (_ext(SPACE, "Discrete", [1, 0, _ext(DTYPE, "|O")], None), "Python objects"),
        (_ext(SPACE, "CustomSpace", [], None), "gymnasium space 'CustomSpace'"),
        (_ext(DTYPE, "|u1" * 100), "dtype string of 300 characters"),
    ):
        with pytest.raises(errors.IsolationError, match=said):
            decode(_forged(["ok", value]))
    deep = _ext(TUPLE, [])
    for _ in range(wire.MAX_DEPTH + 1):  # a tuple nested past the limit (it hashed recursively in C: a segfault)
        deep = _ext(TUPLE, [deep])
    with pytest.raises(errors.IsolationError, match="nests values more than"):
        decode(_forged({deep: 1}))


def test_bytes_that_are_no_answer_are_refused_without_building_what_they_announce():
    """msgpack's own limits: no length beyond the message, native nesting bounded; and a pickle is not an answer."""
    import pickle

    for data in (
        b"\xdd\x7f\xff\xff\xff",  # an array of 2**31 items announced in 5 bytes
        b"\xdf\x7f\xff\xff\xff",  # a map of 2**31 pairs
        b"\xc6\x7f\xff\xff\xff",  # 2 GB of bytes
        b"\x91" * 100_000 + b"\xc0",  # nesting 100,000 lists deep
        pickle.dumps(("ok", 1)),
        b"\x81\x91\x01\x02",  # a list as a dict key
    ):
        with pytest.raises((ValueError, TypeError)):
            decode(data)


def test_keys_chosen_to_share_one_hash_are_refused_not_inserted_in_quadratic_time():
    """int (and float, tuple) hashes are not randomized: 20,000 keys i * (2**61 - 1) all hash to 0, and a dict of
    them took 2.5 s to build here from 280 kB (a 1 MB answer: minutes). Refused in dicts, sets, OrderedDicts and
    defaultdicts; a few keys that happen to share a hash (-1 and -2 do) are fine."""
    p = 2**61 - 1
    keys = [msgpack.ExtType(wire.BIG_INT, (i * p).to_bytes(16, "little", signed=True)) for i in range(20_000)]
    collide = b"\xdf" + len(keys).to_bytes(4, "big") + b"".join(msgpack.packb(k) + b"\xc0" for k in keys)
    with pytest.raises(errors.IsolationError, match="share a hash"):
        decode(collide)
    for code in (wire.SET, wire.FROZENSET):
        with pytest.raises(errors.IsolationError, match="share a hash"):
            decode(_forged(_ext(code, keys)))
    for code, items in ((wire.ORDERED_DICT, [[k, None] for k in keys]), (wire.DEFAULT_DICT, [None, [[k, None] for k in keys]])):
        with pytest.raises(errors.IsolationError, match="share a hash"):
            decode(_forged(_ext(code, *items) if code == wire.DEFAULT_DICT else _ext(code, items)))
    honest = {-1: "a", -2: "b", **{i: i for i in range(1000)}}
    assert decode(encode(honest)) == honest and decode(encode(set(honest))) == set(honest)


def test_what_a_second_red_team_pass_found_is_refused_at_decoding():
    """Each from a few bytes to a few MB, each refused while decoding (the parent never builds it, nor later loops or
    allocates when it uses what came back): a stacked Sequence of a MultiBinary(2**29) (39 bytes: 2.5 GB built by
    gymnasium inside decode), spaces whose sample() builds gigabytes, generator states that draw 0 for ever (numpy's
    rejection sampling then loops in C; only SIGKILL ended it), a zero-byte dtype hiding 10**14 elements, seed
    sequence ints numpy splits in quadratic time, one payload copied at each of 64 nesting levels, millions of
    empty containers, and a type name whose lookup made numpy import submodules."""
    import sys

    pcg = np.random.PCG64(1).state
    mt = np.random.MT19937(1).state
    zero_key = {**mt, "state": {"key": np.zeros(624, np.uint32), "pos": 624}}
    seq = {"entropy": 1 << 100_000, "spawn_key": [], "pool_size": 4, "n_children_spawned": 0}
    hidden = {"names": ["a"], "formats": [["V0,V0", [2**31 - 1]]], "offsets": [0], "itemsize": 0, "aligned": False}
    blob = msgpack.packb(b"x" * (1 << 21))
    for _ in range(wire.MAX_DEPTH - 1):  # a 1-tuple around a 1-tuple ... around 2 MB of bytes
        blob = msgpack.packb(msgpack.ExtType(TUPLE, b"\x91" + blob))
    for value, said in (
        (_ext(SPACE, "Sequence", [_ext(SPACE, "MultiBinary", [[2**29]], None), True], None), "would build more than"),
        (_ext(SPACE, "MultiBinary", [[3 << 30]], None), "would build more than"),
        (_ext(SPACE, "Text", [3 * 10**8, 1, "ab"], None), "would build more than"),
        (_ext(RANDOM, "Generator", "PCG64", {**pcg, "state": {"state": 0, "inc": 0}}, None), "even increment"),
        (_ext(RANDOM, "Generator", "MT19937", zero_key, None), "key of zeros"),
        (_ext(RANDOM, "Generator", "PCG64", pcg, seq), "seed sequence whose entropy"),
        (_array(hidden, [65536], False, b""), "of zero bytes"),
        (msgpack.ExtType(SCALAR, b"\x07<i8,<i8" + bytes(16)), "structured numpy scalar in the plain form"),
    ):
        with pytest.raises(errors.IsolationError, match=said):
            decode(_forged(["ok", value]))
    with pytest.raises(errors.IsolationError, match="would build more than"):
        decode(msgpack.packb(["ok", msgpack.ExtType(TUPLE, b"\x91" + blob)]))  # 64 copies of 2 MB
    with pytest.raises(errors.IsolationError, match="would build more than"):
        decode(b"\xdd" + (1 << 22).to_bytes(4, "big") + b"\x80" * (1 << 22))  # 4 MB of empty dicts: 270 MB
    before = set(sys.modules)
    for name in (b"numpy.f2py", b"numpy.matlib", b"numpy.testing"):
        with pytest.raises(errors.IsolationError, match="off the wire's list"):
            decode(_forged(msgpack.ExtType(TYPE, name)))
    assert not {m for m in set(sys.modules) - before if m.startswith("numpy")}


def test_what_a_review_found_comes_back_exactly():
    """Empty numpy strings (itemsize 0), read-only arrays, aligned structured dtypes, and an honest answer of a
    million small dicts: refused as too large (a typed error the parent survives), never as a forged one."""
    from hub_envs.isolation.protocol import error_info

    for x in (np.str_(""), np.bytes_(b""), np.void(b"")):
        back = decode(encode(x))
        assert type(back) is type(x) and back == x
    frozen = np.arange(4.0)
    frozen.flags.writeable = False
    assert not decode(encode(frozen)).flags.writeable and decode(encode(np.arange(4.0))).flags.writeable
    aligned = np.zeros(2, np.dtype([("a", "u1"), ("b", "<f8")], align=True))
    plain = np.zeros(2, np.dtype([("a", "u1"), ("b", "<f8")]))
    for a in (plain, aligned, plain, aligned):  # equal dtypes as numpy compares them: the header cache keeps them apart
        assert decode(encode(a)).dtype.isalignedstruct == a.dtype.isalignedstruct
    with pytest.raises(errors.AnswerTooLargeError, match="numpy arrays rather than many small"):
        decode(encode([{"a": 1} for _ in range(1_500_000)]))
    import enum

    info = error_info(KeyError(enum.IntEnum("Axis", "X Y").Y, "b\udcff"))
    assert decode(encode(info))["args"][0].startswith("(<Axis.Y: 2>, 'b\\udcff')")  # as str(exc) said, surrogate escaped


def test_what_the_second_red_team_pass_found_is_refused_or_kept_apart(monkeypatch):
    """Sequences nested three deep (stacking doubles per level: 297 bytes ran 20 s), seed lists of a million words,
    keys sharing hashes across many containers, a Text whose charset is megabytes, unicode past U+10FFFF (numpy
    hands out strs that break str), and a decoded structured dtype renamed by the user (it was shared with every
    later answer of that layout); a Graph space's values (GraphInstance) travel."""
    seq = _ext(SPACE, "Discrete", [2, 0, _ext(DTYPE, "<i8")], None)
    for _ in range(3):
        seq = _ext(SPACE, "Sequence", [seq, False], None)
    p = 2**61 - 1
    colliding = [
        {msgpack.ExtType(wire.BIG_INT, (k * p + j).to_bytes(16, "little", signed=True)): 0 for k in range(60)} for j in range(40)
    ]
    for value, said in (
        (seq, "Sequence spaces nested more than 2 deep"),
        (
            _ext(
                RANDOM,
                "Generator",
                "PCG64",
                np.random.PCG64(1).state,
                {"entropy": [1] * 2000, "spawn_key": [], "pool_size": 4, "n_children_spawned": 0},
            ),
            "entropy",
        ),
        (colliding, "keys sharing a hash with another across its containers"),
        (_array("<U1", [2], False, (0x41).to_bytes(4, "little") + (0x7FFFFFFF).to_bytes(4, "little")), "beyond U\\+10FFFF"),
        (msgpack.ExtType(SCALAR, b"\x03<U1" + (0x110000).to_bytes(4, "little")), "beyond U\\+10FFFF"),
    ):
        with pytest.raises(errors.IsolationError, match=said):
            decode(_forged(["ok", value]))
    monkeypatch.setattr(wire, "BUDGET_FLOOR", 0)  # the budget as it scales with the answer (no floor)
    text = _ext(SPACE, "Text", [5, 1, "".join(map(chr, range(0x10000, 0x10000 + 600_000)))], None)
    with pytest.raises(errors.AnswerTooLargeError, match="at Text"):
        decode(_forged(["ok", text]))
    monkeypatch.undo()
    two = S.Sequence(S.Sequence(S.Discrete(2)), stack=False)
    assert decode(encode(two)) == two
    data = encode({"obs": np.zeros(2, [("x", "<f4"), ("y", "<f4")])})
    decode(data)["obs"].dtype.names = ("p", "q")
    assert decode(data)["obs"].dtype.names == ("x", "y")
    graph = S.Graph(S.Box(0, 1, (3,)), S.Discrete(4), seed=1).sample()
    back = decode(encode(graph))
    assert type(back) is type(graph) and all(
        (a is None and b is None) or np.array_equal(a, b) for a, b in zip(back, graph, strict=True)
    )
