"""What an env worker sends back: msgpack data with a closed set of checked extension records, never a program;
:func:`encode` raises :class:`Unsendable` for anything else (why, and what can travel: ``docs/isolation.md``).

Example:
    >>> import numpy as np
    >>> from hub_envs.isolation.wire import decode, encode
    >>> back = decode(encode({"x": np.arange(3, dtype=np.float32), "pair": (1, None)}))
    >>> back["x"].dtype, back["pair"]
    (dtype('float32'), (1, None))
    >>> decode(encode(np.random.default_rng(7))).random() == np.random.default_rng(7).random()
    True
    >>> import os
    >>> encode({"f": os.getcwd})  # doctest: +IGNORE_EXCEPTION_DETAIL
    Traceback (most recent call last):
    hub_envs.isolation.wire.Unsendable: ['f'] is a builtin_function_or_method, which an isolated env cannot send ...
"""

from __future__ import annotations

import collections
import math
import struct
import sys
import threading
from typing import Any

import msgpack

from hub_envs.errors import AnswerTooLargeError, IsolationError

#: numpy, imported the first time a value needs it (:func:`_numpy`): a sandboxed worker imports this module before
#: it enters its pid namespace, where OpenBLAS, started by numpy's import, could not start its threads
np: Any = None

TUPLE, BIG_INT, SET, FROZENSET, COMPLEX, RANGE, SLICE = 1, 2, 3, 4, 6, 7, 8
ORDERED_DICT, DEFAULT_DICT, DEQUE, ARRAY, OBJECT_ARRAY, SCALAR, DTYPE, TYPE, SPACE, RANDOM, GRAPH = range(9, 20)
#: the extension records, by code
KINDS = {
    TUPLE: "tuple",
    BIG_INT: "int",
    SET: "set",
    FROZENSET: "frozenset",
    COMPLEX: "complex",
    RANGE: "range",
    SLICE: "slice",
    ORDERED_DICT: "OrderedDict",
    DEFAULT_DICT: "defaultdict",
    DEQUE: "deque",
    ARRAY: "numpy array",
    OBJECT_ARRAY: "numpy object array",
    SCALAR: "numpy scalar",
    DTYPE: "numpy dtype",
    TYPE: "type",
    SPACE: "gymnasium space",
    RANDOM: "numpy random generator",
    GRAPH: "gymnasium GraphInstance",
}
#: extension records nested deeper than this are refused (each level is a Python call while decoding)
MAX_DEPTH = 64
#: at most this many items of a zero-size dtype (``np.empty(n, "V0")`` weighs nothing, whatever ``n`` says)
MAX_EMPTY_ITEMS = 1 << 16
#: at most this many keys of one dict (or items of one set) may share a hash with another (see :func:`_check_hashes`)
MAX_SHARED_HASHES = 64
#: at most this many keys of all the containers of one answer may share a hash with another
MAX_SHARED_HASHES_PER_ANSWER = 1024
#: at most this many items in a seed sequence's entropy or spawn key (numpy makes an array of each, in Python)
MAX_SEED_WORDS = 1024
#: a Sequence space inside a Sequence inside a Sequence is refused (gymnasium stacks and samples them exponentially)
MAX_SEQUENCE_NESTING = 2
#: the decoder of the answer being decoded in this thread (records charge it)
_ACTIVE = threading.local()
#: an :data:`ARRAY` record starts with the length of its header
_HEAD = struct.Struct("<I")


class Unsendable(TypeError):
    """A value an isolated env returned that the wire cannot carry (the worker reports it as the env's error)."""


def _refuse(what: str) -> IsolationError:
    return IsolationError(
        f"the env worker sent an answer that {what}, which the parent refuses to build. Return plain data from the env."
    )


# -- types as values --------------------------------------------------------------------------------------------

_BUILTIN_TYPES = (bool, int, float, complex, str, bytes, bytearray, list, tuple, dict, set, frozenset, range, slice)
_COLLECTION_TYPES = (collections.OrderedDict, collections.defaultdict, collections.deque)


def _type_name(t: type) -> str | None:
    if t in _BUILTIN_TYPES:
        return t.__name__
    if t in _COLLECTION_TYPES:
        return f"collections.{t.__name__}"
    if vars(np).get(t.__name__) is t and issubclass(t, np.generic):
        return f"numpy.{t.__name__}"
    dtypes = sys.modules.get("numpy.dtypes")
    if dtypes is not None and vars(dtypes).get(t.__name__) is t:
        return f"numpy.dtypes.{t.__name__}"
    return None


def _type_named(name: str) -> type:
    for t in _BUILTIN_TYPES:
        if name == t.__name__:
            return t
    for t in _COLLECTION_TYPES:
        if name == f"collections.{t.__name__}":
            return t
    module, _, attr = name.rpartition(".")  # looked up in what is loaded: numpy's __getattr__ imports submodules
    found = vars(sys.modules[module]).get(attr) if module in ("numpy", "numpy.dtypes") and module in sys.modules else None
    if isinstance(found, type) and _type_name(found) == name:
        return found
    raise _refuse(f"names a type ({name!r}) off the wire's list")


def type_names() -> list[str]:
    """The types an answer may hold as values (``defaultdict(list)``'s factory, ``np.float32`` in an info).

    >>> "numpy.float32" in type_names() and "list" in type_names()
    True
    """
    _numpy()
    names = [_type_name(t) for t in (*_BUILTIN_TYPES, *_COLLECTION_TYPES)]
    names += sorted(f"numpy.{n}" for n, t in vars(np).items() if isinstance(t, type) and _type_name(t) == f"numpy.{n}")
    return names


# -- encoding (the worker) ----------------------------------------------------------------------------------------


def _pack(obj: Any) -> bytes:
    return msgpack.packb(obj, default=_default, strict_types=True, use_bin_type=True)


def _dtype_desc(dt: np.dtype) -> Any:
    if dt.fields is not None:
        names = list(dt.names)
        return {
            "names": names,
            "formats": [_dtype_desc(dt.fields[n][0]) for n in names],
            "offsets": [dt.fields[n][1] for n in names],
            "itemsize": dt.itemsize,
            "aligned": dt.isalignedstruct,
        }
    if dt.subdtype is not None:
        return [_dtype_desc(dt.subdtype[0]), list(dt.subdtype[1])]
    return dt.str


def _array(a: np.ndarray) -> msgpack.ExtType:
    if a.dtype.hasobject:
        if a.dtype != np.dtype(object):
            raise Unsendable(f"a numpy array of dtype {a.dtype} (its items are Python objects: use a plain dtype)")
        return msgpack.ExtType(OBJECT_ARRAY, _pack([list(a.shape), a.ravel().tolist() if a.ndim else [a.item()]]))
    fortran = a.ndim > 1 and a.flags.f_contiguous and not a.flags.c_contiguous
    writeable = a.flags.writeable
    key = (a.dtype, a.dtype.isalignedstruct, a.shape, fortran, writeable)  # equal dtypes may differ in alignment
    head = _ARRAY_HEADS_OUT.get(key)
    if head is None:
        head = _pack([_dtype_desc(a.dtype), list(a.shape), fortran] + ([] if writeable else [False]))
        head = _HEAD.pack(len(head)) + head
        if len(_ARRAY_HEADS_OUT) >= _CACHED_HEADS:
            _ARRAY_HEADS_OUT.clear()
        _ARRAY_HEADS_OUT[key] = head
    if a.size == 0 or a.dtype.itemsize == 0:
        data: Any = b""
    else:  # the bytes in memory order without a copy when they are contiguous (a copy of a big array is page faults)
        flat = a.T if fortran else a if a.flags.c_contiguous else np.ascontiguousarray(a)
        data = memoryview(flat.reshape(-1).view(np.uint8))
    return msgpack.ExtType(ARRAY, head + data if type(data) is bytes else b"".join((head, data)))


#: the headers of the array records a worker sent or read last (most envs send the same few layouts every step)
_CACHED_HEADS = 256
_ARRAY_HEADS_OUT: dict[tuple, bytes] = {}
_ARRAY_HEADS_IN: dict[bytes, tuple] = {}


def _scalar(x: np.generic) -> msgpack.ExtType:
    """A :data:`SCALAR` record: the length of the dtype's string, the string, the scalar's bytes; or, for a
    structured scalar, a zero byte and the :data:`ARRAY` record of it as a 0-d array."""
    dt = x.dtype
    if dt.hasobject:
        raise Unsendable("a numpy scalar holding Python objects")
    if dt.fields is not None:
        return msgpack.ExtType(SCALAR, b"\0" + _array(np.array(x)).data)
    desc = dt.str.encode()
    data = x.tobytes() if dt.itemsize else b""  # np.str_("") (<U0) gives 4 bytes of nothing
    return msgpack.ExtType(SCALAR, b"".join((bytes([len(desc)]), desc, data)))


def _generator_desc(obj: Any) -> list:
    if isinstance(obj, np.random.Generator) and type(obj) is np.random.Generator:
        kind, bg, extra = "Generator", obj.bit_generator, None
    elif type(obj) is np.random.RandomState:
        kind, extra = "RandomState", obj.get_state(legacy=False)
        bg = obj._bit_generator
    else:
        kind, bg, extra = "BitGenerator", obj, None
    name = type(bg).__name__
    if name not in _BIT_GENERATORS or type(bg) is not getattr(np.random, name):
        raise Unsendable(f"a random generator over a {type(bg).__module__}.{type(bg).__qualname__}")
    seq = getattr(bg, "seed_seq", None)
    seq_state = seq.state if type(seq) is np.random.SeedSequence else None
    return [kind, name, bg.state if extra is None else extra, seq_state]


def _space_desc(space: Any) -> list:
    from gymnasium import spaces as s

    kind = type(space).__name__
    if getattr(s, kind, None) is not type(space):
        raise Unsendable(f"a space of class {type(space).__module__}.{type(space).__qualname__} (only gymnasium's own spaces)")
    if kind == "Box":
        args: Any = [space.low, space.high]
    elif kind == "Discrete":
        args = [int(space.n), int(space.start), np.dtype(getattr(space, "dtype", np.int64))]
    elif kind == "MultiDiscrete":
        args = [space.nvec, space.start, space.dtype]
    elif kind == "MultiBinary":
        args = [space.n if isinstance(space.n, int) else [int(i) for i in space.n]]
    elif kind == "Text":
        args = [space.max_length, space.min_length, "".join(space.character_list)]
    elif kind == "Dict":
        args = [[[k, v] for k, v in space.spaces.items()]]
    elif kind in ("Tuple", "OneOf"):
        args = [list(space.spaces)]
    elif kind == "Sequence":
        args = [space.feature_space, bool(space.stack)]
    elif kind == "Graph":
        args = [space.node_space, space.edge_space]
    else:
        raise Unsendable(f"a gymnasium {kind} space")
    return [kind, args, space._np_random]


def _encode_space(x: Any) -> msgpack.ExtType:
    return msgpack.ExtType(SPACE, _pack(_space_desc(x)))


def _encode_random(x: Any) -> msgpack.ExtType:
    return msgpack.ExtType(RANDOM, _pack(_generator_desc(x)))


def _encode_type(t: type) -> msgpack.ExtType:
    name = _type_name(t)
    if name is None:
        raise Unsendable(f"the type {t.__module__}.{t.__qualname__} (types travel only from a fixed list)")
    return msgpack.ExtType(TYPE, name.encode())


def _encode_int(n: int) -> msgpack.ExtType:
    return msgpack.ExtType(BIG_INT, n.to_bytes(n.bit_length() // 8 + 1, "little", signed=True))


def _encode_default_dict(d: collections.defaultdict) -> msgpack.ExtType:
    factory = d.default_factory
    if factory is not None and not isinstance(factory, type):
        raise Unsendable(f"a defaultdict whose factory is a {type(factory).__name__} (only a type from the wire's list)")
    return msgpack.ExtType(DEFAULT_DICT, _pack([factory, [[k, v] for k, v in d.items()]]))


_BIT_GENERATORS = ("PCG64", "PCG64DXSM", "MT19937", "Philox", "SFC64")
_ENCODERS: dict[type, Any] = {}


def _numpy() -> Any:
    """numpy, and the table of encoders by exact type, on first use."""
    global np
    if np is None:
        import numpy

        _ENCODERS.update(
            {
                tuple: lambda x: msgpack.ExtType(TUPLE, _pack(list(x))),
                int: _encode_int,
                set: lambda x: msgpack.ExtType(SET, _pack(list(x))),
                frozenset: lambda x: msgpack.ExtType(FROZENSET, _pack(list(x))),
                complex: lambda x: msgpack.ExtType(COMPLEX, _pack([x.real, x.imag])),
                range: lambda x: msgpack.ExtType(RANGE, _pack([x.start, x.stop, x.step])),
                slice: lambda x: msgpack.ExtType(SLICE, _pack([x.start, x.stop, x.step])),
                collections.OrderedDict: lambda x: msgpack.ExtType(ORDERED_DICT, _pack([[k, v] for k, v in x.items()])),
                collections.defaultdict: _encode_default_dict,
                collections.deque: lambda x: msgpack.ExtType(DEQUE, _pack([list(x), x.maxlen])),
                numpy.ndarray: _array,
                numpy.random.Generator: _encode_random,
                numpy.random.RandomState: _encode_random,
            }
        )
        for name in _BIT_GENERATORS:
            _ENCODERS[getattr(numpy.random, name)] = _encode_random
        np = numpy
    return np


def _default(obj: Any) -> Any:
    if np is None:
        _numpy()
    kind = type(obj)
    encoder = _ENCODERS.get(kind)
    if encoder is not None:
        return encoder(obj)
    if isinstance(obj, np.generic):
        return _scalar(obj)
    if kind is np.dtype or isinstance(obj, np.dtype):
        return msgpack.ExtType(DTYPE, _pack(_dtype_desc(obj)))
    if isinstance(obj, type):
        return _encode_type(obj)
    spaces = sys.modules.get("gymnasium.spaces")
    if spaces is not None and isinstance(obj, spaces.Space):
        return _encode_space(obj)
    if spaces is not None and kind is getattr(spaces, "GraphInstance", None):  # a Graph space's value
        return msgpack.ExtType(GRAPH, _pack([obj.nodes, obj.edges, obj.edge_links]))
    raise Unsendable(
        f"of type {kind.__module__}.{kind.__qualname__}" if kind.__module__ != "builtins" else f"of type {kind.__qualname__}"
    )


def _where(obj: Any, path: str, depth: int = 0) -> tuple[str, str] | None:
    """Where in ``obj`` the first value the wire cannot carry is, and why (for the error message)."""
    try:
        _pack(obj)
        return None
    except Unsendable as e:
        why = str(e)
    except (ValueError, OverflowError, TypeError) as e:
        why = f"{type(e).__name__}: {e}"
    if depth < 20:
        kind = type(obj)
        items: Any = ()
        if kind in (dict, collections.OrderedDict, collections.defaultdict):
            items = ((f"[{k!r}]", v) for k, v in obj.items())
        elif kind in (list, tuple, collections.deque):
            items = ((f"[{i}]", v) for i, v in enumerate(obj))
        for sub, value in items:
            found = _where(value, path + sub, depth + 1)
            if found is not None:
                return found
    return path, why


def encode(obj: Any, name: str = "the value") -> bytes:
    """A value as the wire carries it.

    Args:
        obj: plain data, numpy arrays and scalars, gymnasium spaces, numpy random generators (:data:`KINDS`).
        name: what to call ``obj`` in an error (``info``: a value inside is named ``info['x'][0]``).

    Returns:
        Its msgpack bytes.

    Raises:
        Unsendable: naming the first value inside that the wire cannot carry, and why.

    >>> encode([1, "a"]) == b"\\x92\\x01\\xa1a"
    True
    """
    try:
        return _pack(obj)
    except (Unsendable, ValueError, OverflowError, TypeError):
        found = _where(obj, name)
        where, why = found if found is not None else (name, "unknown")
        raise Unsendable(
            f"{where} is {why}, which an isolated env cannot send to its parent (it sends plain data, numpy arrays and "
            f"scalars, gymnasium spaces and numpy random generators)"
        ) from None


# -- decoding (the parent) ----------------------------------------------------------------------------------------


def _int(x: Any, what: str, low: int = 0, high: int | None = None) -> int:
    if type(x) is not int or x < low or (high is not None and x > high):
        raise _refuse(f"holds {what} {x!r} (not an int in [{low}, {'...' if high is None else high}])")
    return x


def _shape(x: Any) -> tuple[int, ...]:
    if type(x) is not list or len(x) > 64:
        raise _refuse(f"holds an array shape {x!r}")
    return tuple(_int(n, "an array dimension", 0, 1 << 62) for n in x)


def _dtype(desc: Any, depth: int = 0) -> np.dtype:
    if depth > 16:
        raise _refuse("holds a dtype nested too deep")
    try:
        if type(desc) is str:
            if len(desc) > 64:
                raise _refuse(f"holds a dtype string of {len(desc)} characters")
            dt = np.dtype(desc)
        elif type(desc) is list and len(desc) == 2:
            base = _dtype(desc[0], depth + 1)
            shape = _shape(desc[1])
            if math.prod(shape) * base.itemsize > 1 << 31:
                raise _refuse(f"holds a dtype of {shape!r} items")
            dt = np.dtype((base, shape))
        elif type(desc) is dict and set(desc) == {"names", "formats", "offsets", "itemsize", "aligned"}:
            names, formats, offsets = desc["names"], desc["formats"], desc["offsets"]
            if not (type(names) is type(formats) is type(offsets) is list and len(names) == len(formats) == len(offsets)):
                raise _refuse("holds a malformed structured dtype")
            dt = np.dtype(
                {
                    "names": names,
                    "formats": [_dtype(f, depth + 1) for f in formats],
                    "offsets": [_int(o, "a field offset", 0, 1 << 31) for o in offsets],
                    "itemsize": _int(desc["itemsize"], "an itemsize", 0, 1 << 31),
                },
                align=desc["aligned"] is True,
            )
        else:
            raise _refuse(f"holds a dtype description of type {type(desc).__name__}")
    except (TypeError, ValueError) as e:
        raise _refuse(f"holds a dtype numpy refuses ({e})") from None
    if dt.hasobject:
        raise _refuse("holds a dtype of Python objects read from raw bytes")
    _check_layout(dt)
    return dt


def _fields(dt: Any) -> int:
    """How many fields and subarrays ``dt`` holds, at every level."""
    if dt.subdtype is not None:
        return 1 + _fields(dt.subdtype[0])
    return sum(1 + _fields(dt.fields[n][0]) for n in dt.names) if dt.names else 0


def _check_layout(dt: Any) -> None:
    """Refuse a dtype with a subarray or fields of zero bytes: such items weigh nothing whatever they claim to
    hold, so an array of them that says it is small can hold 10**14 elements once a field is taken."""
    if dt.subdtype is not None:
        base, shape = dt.subdtype
        if base.itemsize == 0 and math.prod(shape) > 1:
            raise _refuse(f"holds a dtype of {shape!r} items of zero bytes")
        _check_layout(base)
    if dt.fields is not None:
        if dt.itemsize == 0 and dt.names:
            raise _refuse("holds a structured dtype of zero bytes")
        for name in dt.names:
            _check_layout(dt.fields[name][0])


def _decode_array(payload: bytes) -> np.ndarray:
    """An :data:`ARRAY` record: the header's length (:data:`_HEAD`), the header ``[dtype, shape, fortran]`` (plain
    msgpack; ``[..., False]`` for an array that was read-only), then the array's bytes in memory order."""
    if len(payload) < _HEAD.size:
        raise _refuse("holds a malformed numpy array")
    (n,) = _HEAD.unpack_from(payload)
    start = _HEAD.size + n
    if start > len(payload):
        raise _refuse("holds a numpy array whose header is longer than the record")
    head = payload[:start]
    layout = _ARRAY_HEADS_IN.get(head)
    if layout is None:
        items = msgpack.unpackb(
            payload[_HEAD.size : start], raw=False, max_array_len=4096, max_map_len=8, max_str_len=4096, max_bin_len=0
        )
        if type(items) is not list or len(items) not in (3, 4) or type(items[2]) is not bool or items[3:] not in ([], [False]):
            raise _refuse("holds a malformed numpy array")
        desc, shape, fortran = items[:3]
        dt, shape = _dtype(desc), _shape(shape)
        layout = (dt, shape, fortran, math.prod(shape), len(items) == 3)
        if dt.names is not None or dt.subdtype is not None:  # fields are objects of their own (and names mutable)
            _charge(160 * _fields(dt), "a structured dtype")
        elif n <= 256:  # a shared dtype only when nothing of it can be renamed
            if len(_ARRAY_HEADS_IN) >= _CACHED_HEADS:
                _ARRAY_HEADS_IN.clear()
            _ARRAY_HEADS_IN[head] = layout
    dt, shape, fortran, count, writeable = layout
    size = len(payload) - start
    if dt.itemsize == 0:
        if count > MAX_EMPTY_ITEMS or size:
            raise _refuse(f"asks for {count:,} items of an empty dtype")
        out = np.empty(shape, dt)
    elif count * dt.itemsize != size:
        raise _refuse(f"asks for an array of {count * dt.itemsize:,} bytes ({dt}, shape {shape}) from {size:,} bytes")
    else:  # over a copy of the bytes (padding included)
        out = np.frombuffer(bytearray(memoryview(payload)[start:]), dt, count).reshape(shape, order="F" if fortran else "C")
    if dt.kind == "U" or (dt.names is not None or dt.subdtype is not None) and "U" in str(dt):
        _check_text(out)
    if not writeable:  # as the env's own array was
        out.flags.writeable = False
    return out


def _check_text(a: np.ndarray) -> None:
    """Refuse unicode arrays holding code points no Python str may (above U+10FFFF: numpy hands them out as strs
    that break str's invariants, SystemError in iteration or upper())."""
    if a.dtype.names is not None:
        for name in a.dtype.names:
            _check_text(a[name])
        return
    if a.dtype.subdtype is not None or a.dtype.kind != "U" or not a.size or not a.dtype.itemsize:
        return
    codes = np.ascontiguousarray(a).view(a.dtype.byteorder.replace("|", "=") + "u4" if a.dtype.byteorder != "=" else "=u4")
    if codes.size and int(codes.max()) > 0x10FFFF:
        raise _refuse("holds text with code points beyond U+10FFFF")


def _decode_object_array(items: Any) -> np.ndarray:
    if type(items) is not list or len(items) != 2 or type(items[1]) is not list:
        raise _refuse("holds a malformed numpy object array")
    shape, values = _shape(items[0]), items[1]
    if math.prod(shape) != max(len(values), 0) or (not shape and len(values) != 1):
        raise _refuse(f"asks for an object array of shape {shape} from {len(values):,} items")
    out = np.empty(len(values), dtype=object)
    for i, v in enumerate(values):
        out[i] = v
    return out.reshape(shape)


_SCALAR_DTYPES: dict[bytes, Any] = {}


def _decode_scalar(payload: bytes) -> np.generic:
    if not payload:
        raise _refuse("holds a malformed numpy scalar")
    n = payload[0]
    if n == 0:  # a structured scalar, as a 0-d array
        array = _decode_array(payload[1:])
        if array.shape != () or array.dtype.fields is None:
            raise _refuse("holds a structured numpy scalar that is not one")
        return array[()]
    desc = payload[1 : 1 + n]
    dt = _SCALAR_DTYPES.get(desc)
    if dt is None:
        dt = _dtype(desc.decode("ascii", "replace"))
        if len(_SCALAR_DTYPES) >= _CACHED_HEADS:
            _SCALAR_DTYPES.clear()
        _SCALAR_DTYPES[desc] = dt
    if dt.fields is not None or dt.subdtype is not None:
        raise _refuse("holds a structured numpy scalar in the plain form")
    if dt.itemsize == 0 and len(payload) == 1 + n:
        return np.zeros((), dt)[()]
    if dt.kind == "U" and len(payload) - 1 - n == dt.itemsize:
        _check_text(np.frombuffer(payload, dt, 1, 1 + n))
    if len(payload) - 1 - n != dt.itemsize:
        raise _refuse(f"asks for a numpy {dt} scalar of {dt.itemsize} bytes from {len(payload) - 1 - n} bytes")
    return np.frombuffer(payload, dt, 1, 1 + n)[0]


def _checked_state(name: str, state: Any) -> dict:
    """A bit generator's state, with every position numpy indexes by checked (numpy's setters do not: an MT19937
    ``pos`` past its key reads out of bounds), and none of the states that give 0 forever (numpy's rejection
    sampling, ``integers`` or a space's ``sample``, would then loop in C for ever): a PCG64 increment is odd, an
    MT19937 key has a set bit where the generator reads it."""

    def arr(x, n):
        if type(x) is not np.ndarray or x.shape != (n,) or x.dtype != (np.uint32 if name == "MT19937" else np.uint64):
            raise _refuse(f"holds a {name} state array that is not {n} words")
        return x

    if type(state) is not dict or state.get("bit_generator") != name or type(state.get("state")) is not dict:
        raise _refuse(f"holds a malformed {name} state")
    inner = state["state"]
    if name == "MT19937":
        key = arr(inner.get("key"), 624)
        _int(inner.get("pos"), "an MT19937 position", 0, 624)
        if not (int(key[0]) & 0x80000000 or key[1:].any()):
            raise _refuse("holds an MT19937 key of zeros (it would draw 0 for ever)")
    else:
        _int(state.get("has_uint32"), "a has_uint32 flag", 0, 1)
        _int(state.get("uinteger"), "a buffered uint32", 0, (1 << 32) - 1)
        if name in ("PCG64", "PCG64DXSM"):
            for k in ("state", "inc"):
                _int(inner.get(k), f"a {name} {k}", 0, (1 << 128) - 1)
            if not inner["inc"] & 1:  # numpy's seeding makes it odd; an even one can give 0 for ever
                raise _refuse(f"holds a {name} state with an even increment")
        elif name == "Philox":
            arr(inner.get("counter"), 4), arr(inner.get("key"), 2), arr(state.get("buffer"), 4)
            _int(state.get("buffer_pos"), "a Philox buffer position", 0, 4)
        else:  # SFC64
            arr(inner.get("state"), 4)
    return state


def _decode_random(items: Any) -> Any:
    if type(items) is not list or len(items) != 4:
        raise _refuse("holds a malformed random generator")
    kind, name, state, seq_state = items
    if kind not in ("Generator", "RandomState", "BitGenerator") or name not in _BIT_GENERATORS:
        raise _refuse(f"holds a random generator {kind!r} over {name!r}")
    seq = None
    if seq_state is not None:
        if type(seq_state) is not dict or set(seq_state) != {"entropy", "spawn_key", "pool_size", "n_children_spawned"}:
            raise _refuse("holds a malformed seed sequence")
        entropy, key = seq_state["entropy"], seq_state["spawn_key"]
        # numpy splits big ints into words in a quadratic Python loop: entropy and keys stay small
        if entropy is not None and not (type(entropy) is int and 0 <= entropy < 1 << 4096):
            if (
                type(entropy) not in (list, tuple)
                or len(entropy) > MAX_SEED_WORDS
                or not all(type(e) is int and 0 <= e < 1 << 128 for e in entropy)
            ):
                raise _refuse("holds a seed sequence whose entropy is not a few small non-negative integers")
        if (
            type(key) not in (list, tuple)
            or len(key) > MAX_SEED_WORDS
            or not all(type(k) is int and 0 <= k < 1 << 128 for k in key)
        ):
            raise _refuse("holds a seed sequence whose spawn key is not a few small non-negative integers")
        seq = np.random.SeedSequence(
            entropy,
            spawn_key=tuple(key),
            pool_size=_int(seq_state["pool_size"], "a seed pool size", 4, 64),
            n_children_spawned=_int(seq_state["n_children_spawned"], "a spawned-children count", 0, (1 << 32) - 1),
        )
    if kind == "RandomState":
        if type(state) is not dict:
            raise _refuse("holds a malformed RandomState")
        _int(state.get("has_gauss"), "a has_gauss flag", 0, 1)
        if type(state.get("gauss")) is not float or not math.isfinite(state["gauss"]):
            raise _refuse("holds a RandomState whose gauss is not a finite float")
        inner = {"bit_generator": "MT19937", "state": state.get("state")}
        _checked_state("MT19937", inner)
        if name != "MT19937":
            raise _refuse("holds a RandomState over another bit generator than MT19937")
    else:
        _checked_state(name, state)
    bg = getattr(np.random, name)(seq)
    try:
        if kind == "RandomState":
            rs = np.random.RandomState(bg)
            rs.set_state(state)
            return rs
        bg.state = state
    except (TypeError, ValueError, KeyError) as e:
        raise _refuse(f"holds a {name} state numpy refuses ({e})") from None
    return np.random.Generator(bg) if kind == "Generator" else bg


def _elements(space: Any) -> int:
    """How many values one sample of ``space`` holds (what its ``sample()`` and a batch of it build)."""
    parts = getattr(space, "spaces", None)
    if parts is not None:
        return sum(_elements(p) for p in (parts.values() if isinstance(parts, dict) else parts))
    for sub in ("feature_space", "node_space"):
        if hasattr(space, sub):
            return _elements(getattr(space, sub)) + (_elements(space.edge_space) if getattr(space, "edge_space", None) else 0)
    if hasattr(space, "max_length"):
        return int(space.max_length)
    return max(1, math.prod(space.shape or (1,)))


def _sequence_depth(space: Any) -> int:
    """How many Sequence spaces are nested in ``space`` (itself included), at most."""
    from gymnasium import spaces as s

    parts = getattr(space, "spaces", None)
    if parts is not None:
        return max((_sequence_depth(p) for p in (parts.values() if isinstance(parts, dict) else parts)), default=0)
    if isinstance(space, s.Sequence):
        return 1 + _sequence_depth(space.feature_space)
    if isinstance(space, s.Graph):
        return max(_sequence_depth(space.node_space), _sequence_depth(space.edge_space) if space.edge_space else 0)
    return 0


def _decode_graph(items: Any) -> Any:
    from gymnasium.spaces import GraphInstance

    if type(items) is not list or len(items) != 3 or not all(x is None or type(x) is np.ndarray for x in items):
        raise _refuse("holds a malformed GraphInstance")
    return GraphInstance(*items)


def _decode_space(items: Any) -> Any:
    from gymnasium import spaces as s

    if type(items) is not list or len(items) != 3 or type(items[1]) is not list:
        raise _refuse("holds a malformed gymnasium space")
    kind, args, rng = items
    if kind == "MultiBinary" and len(args) == 1:  # what its sample() will build
        _charge(8 * math.prod(_shape(args[0]) if type(args[0]) is list else (_int(args[0], "a MultiBinary n", 1),)), kind)
    elif kind == "Text" and len(args) == 3:  # its sample(), and a dict, a list and a str per character of its charset
        _charge(8 * _int(args[0], "a Text max_length", 0, 1 << 62) + 128 * len(str(args[2])), kind)
    elif kind == "Sequence" and len(args) == 2 and isinstance(args[0], s.Space):
        if _sequence_depth(args[0]) >= MAX_SEQUENCE_NESTING:  # stacking and sampling grow exponentially with it
            raise _refuse(f"holds Sequence spaces nested more than {MAX_SEQUENCE_NESTING} deep")
        if args[1] is True:
            _charge(16 * _elements(args[0]), "a stacked Sequence")  # built here (batch_space), and by each sample()
    elif kind == "Box" and len(args) == 2 and type(args[0]) is np.ndarray:
        _charge(6 * args[0].nbytes, kind)  # the bounds, cast and compared
    elif kind == "Graph" and len(args) == 2 and all(a is None or isinstance(a, s.Space) for a in args):
        # its sample() draws up to 10 nodes and 90 edges, each a sample of the node / edge space, in float64
        _charge(80 * _elements(args[0]) + (720 * _elements(args[1]) if args[1] is not None else 0), kind)

    def space(x):
        if not isinstance(x, s.Space):
            raise _refuse(f"holds a {kind} space over a {type(x).__name__}")
        return x

    try:
        if kind == "Box" and len(args) == 2:
            low, high = args
            if type(low) is not np.ndarray or type(high) is not np.ndarray or low.shape != high.shape or low.dtype != high.dtype:
                raise _refuse("holds a Box whose bounds are not two arrays of one shape and dtype")
            built: Any = s.Box(low, high, dtype=low.dtype)
        elif kind == "Discrete" and len(args) == 3:
            n, start, dtype = _int(args[0], "a Discrete n", 1, 1 << 62), args[1], args[2]
            if type(start) is not int or not isinstance(dtype, np.dtype):
                raise _refuse("holds a malformed Discrete space")
            built = s.Discrete(n, start=start) if dtype == np.int64 else s.Discrete(n, start=start, dtype=dtype)
        elif kind == "MultiDiscrete" and len(args) == 3:
            nvec, start, dtype = args
            if type(nvec) is not np.ndarray or type(start) is not np.ndarray or not isinstance(dtype, np.dtype):
                raise _refuse("holds a malformed MultiDiscrete space")
            built = s.MultiDiscrete(nvec, dtype=dtype, start=start)
        elif kind == "MultiBinary" and len(args) == 1:
            n = args[0]
            built = s.MultiBinary(_int(n, "a MultiBinary n", 1, 1 << 62) if type(n) is not list else list(_shape(n)))
        elif kind == "Text" and len(args) == 3:
            if type(args[2]) is not str:
                raise _refuse("holds a Text space whose charset is not a str")
            built = s.Text(
                _int(args[0], "a Text max_length", 0, 1 << 62), min_length=_int(args[1], "a Text min_length"), charset=args[2]
            )
        elif kind == "Dict" and len(args) == 1 and type(args[0]) is list:
            pairs = []
            for pair in args[0]:
                if type(pair) is not list or len(pair) != 2:
                    raise _refuse("holds a malformed Dict space")
                pairs.append((pair[0], space(pair[1])))
            _check_hashes([k for k, _ in pairs], "Dict space")
            built = s.Dict(pairs)
        elif kind in ("Tuple", "OneOf") and len(args) == 1 and type(args[0]) is list:
            built = getattr(s, kind)([space(x) for x in args[0]])
        elif kind == "Sequence" and len(args) == 2 and type(args[1]) is bool:
            built = s.Sequence(space(args[0]), stack=args[1])
        elif kind == "Graph" and len(args) == 2:
            built = s.Graph(space(args[0]), None if args[1] is None else space(args[1]))
        else:
            raise _refuse(f"holds a gymnasium space {kind!r} with {len(args)} arguments")
    except IsolationError:
        raise
    except (TypeError, ValueError, AssertionError) as e:
        raise _refuse(f"holds a {kind} space gymnasium refuses ({e})") from None
    if rng is not None:
        if type(rng) is not np.random.Generator:
            raise _refuse(f"holds a space whose random generator is a {type(rng).__name__}")
        built._np_random = rng
    return built


def _check_hashes(keys: list, what: str) -> None:
    """Refuse keys (or set items) of which many share one hash: Python's hashes of ints, floats and tuples of them
    are not randomized, so a sender can pick thousands of keys a dict must compare with each other (a HashDoS:
    quadratic time after the watchdog). ``str`` and ``bytes`` hashes are keyed per process."""
    if len(keys) < 2 or all(type(k) is str for k in keys):
        return
    hashes = [hash(k) for k in keys]  # an unhashable key: TypeError, as building the dict would raise
    shared = len(hashes) - len(set(hashes))
    if shared > MAX_SHARED_HASHES:
        raise _refuse(f"holds a {what} of {len(keys):,} keys of which {shared:,} share a hash (a hash-collision attack)")
    dec = getattr(_ACTIVE, "decoder", None)
    if shared and dec is not None:  # many containers of a few colliding keys each (with long equal prefixes)
        dec.shared += shared
        if dec.shared > MAX_SHARED_HASHES_PER_ANSWER:
            raise _refuse(f"holds {dec.shared:,} keys sharing a hash with another across its containers")


def _pairs(items: Any, what: str) -> list:
    if type(items) is not list or any(type(p) is not list or len(p) != 2 for p in items):
        raise _refuse(f"holds a malformed {what}")
    _check_hashes([p[0] for p in items], what)
    return items


def _decode_default_dict(items: Any) -> collections.defaultdict:
    if type(items) is not list or len(items) != 2:
        raise _refuse("holds a malformed defaultdict")
    factory = items[0]
    if factory is not None and not isinstance(factory, type):
        raise _refuse(f"holds a defaultdict whose factory is a {type(factory).__name__}")
    return collections.defaultdict(factory, _pairs(items[1], "defaultdict"))


def _decode_deque(items: Any) -> collections.deque:
    if type(items) is not list or len(items) != 2 or type(items[0]) is not list:
        raise _refuse("holds a malformed deque")
    maxlen = items[1]
    return collections.deque(items[0], None if maxlen is None else _int(maxlen, "a deque maxlen"))


def _three(items: Any, what: str) -> list:
    if type(items) is not list or len(items) != 3:
        raise _refuse(f"holds a malformed {what}")
    return items


def _decode_range(items: Any) -> range:
    start, stop, step = _three(items, "range")
    if not all(type(v) is int for v in (start, stop, step)):
        raise _refuse("holds a range of non-integers")
    return range(start, stop, step)


def _decode_complex(items: Any) -> complex:
    if type(items) is not list or len(items) != 2 or not all(type(v) is float for v in items):
        raise _refuse("holds a malformed complex")
    return complex(items[0], items[1])


def _decode_items(code: int):
    def build(items: Any) -> Any:
        if type(items) is not list:
            raise _refuse(f"holds a malformed {KINDS[code]}")
        if code != TUPLE:
            _check_hashes(items, KINDS[code])
        return {TUPLE: tuple, SET: set, FROZENSET: frozenset}[code](items)

    return build


_DECODERS: dict[int, Any] = {
    TUPLE: _decode_items(TUPLE),
    SET: _decode_items(SET),
    FROZENSET: _decode_items(FROZENSET),
    COMPLEX: _decode_complex,
    RANGE: _decode_range,
    SLICE: lambda items: slice(*_three(items, "slice")),
    ORDERED_DICT: lambda items: collections.OrderedDict(_pairs(items, "OrderedDict")),
    DEFAULT_DICT: _decode_default_dict,
    DEQUE: _decode_deque,
    OBJECT_ARRAY: _decode_object_array,
    DTYPE: _dtype,
    SPACE: _decode_space,
    GRAPH: _decode_graph,
    RANDOM: _decode_random,
}
#: records whose payload is raw bytes, not msgpack
_RAW = {
    BIG_INT: lambda data: int.from_bytes(data, "little", signed=True),
    ARRAY: _decode_array,
    SCALAR: _decode_scalar,
    TYPE: lambda data: _type_named(data.decode("ascii", "replace")),
}


#: roughly what the Python object of each record kind costs beyond its payload (bytes), charged to the budget
_RECORD_COST = {TUPLE: 64, SET: 256, FROZENSET: 256, DEQUE: 640, ORDERED_DICT: 256, DEFAULT_DICT: 256, ARRAY: 512}
_RECORD_COST.update({OBJECT_ARRAY: 512, SCALAR: 96, DTYPE: 256, SPACE: 2048, RANDOM: 4096})
#: a message may build this many bytes of Python objects per byte it weighs, plus :data:`BUDGET_FLOOR`
BUDGET_PER_BYTE = 16
BUDGET_FLOOR = 64 << 20


class _Decoder:
    """One decoding: the depth of records, and a budget of the memory the message may make the parent build
    (:data:`BUDGET_PER_BYTE` per byte it weighs, plus :data:`BUDGET_FLOOR`): lists and maps (msgpack's own
    containers, through its hooks), every record's payload copy and object, and what a space implies (a
    ``MultiBinary(10**9)`` is a few bytes whose ``sample()`` builds a gigabyte; ``Sequence(stack=True)`` builds
    its stacked space at once)."""

    __slots__ = ("depth", "budget", "size", "shared")

    def __init__(self, size: int) -> None:
        self.depth = 0
        self.shared = 0
        self.size = size
        self.budget = BUDGET_PER_BYTE * size + BUDGET_FLOOR

    def charge(self, nbytes: int, what: str) -> None:
        self.budget -= nbytes
        if self.budget < 0:
            raise AnswerTooLargeError(
                f"the env worker sent an answer of {self.size:,} bytes that would build more than "
                f"{BUDGET_PER_BYTE * self.size + BUDGET_FLOOR:,} bytes of Python objects (at {what}); the parent refused "
                f"it. Return numpy arrays rather than many small dicts, lists or tuples."
            )

    def load(self, data: bytes) -> Any:
        return msgpack.unpackb(
            data,
            ext_hook=self.ext,
            object_pairs_hook=self.pairs,
            list_hook=self.list,
            strict_map_key=False,
            raw=False,
            use_list=True,
        )

    def list(self, items: list) -> list:
        self.charge(56 + 64 * len(items), "a list")  # its slots, and items that are objects of their own ("ā": 76 B)
        return items

    def pairs(self, pairs: list) -> dict:
        """Every msgpack map: a dict of its pairs once :func:`_check_hashes` passed."""
        self.charge(64 + 128 * len(pairs), "a dict")  # the table, and keys and values that are objects of their own
        if len(pairs) > 1:
            _check_hashes([k for k, _ in pairs], "dict")
        return dict(pairs)

    def ext(self, code: int, data: bytes) -> Any:
        if np is None:
            _numpy()
        self.charge(_RECORD_COST.get(code, 64) + len(data), KINDS.get(code, "a record"))  # the payload's copy too
        raw = _RAW.get(code)
        if raw is not None:
            if code == BIG_INT and len(data) > 1 << 20:
                raise _refuse(f"holds an integer of {len(data):,} bytes")
            return raw(data)
        build = _DECODERS.get(code)
        if build is None:
            raise _refuse(f"holds an extension record of unknown kind {code}")
        if self.depth >= MAX_DEPTH:
            raise _refuse(f"nests values more than {MAX_DEPTH} records deep")
        self.depth += 1
        try:
            built = build(self.load(data))
            if code == DTYPE and (built.names or built.subdtype):  # a structured dtype's fields cost their own objects
                self.charge(160 * _fields(built), "a structured dtype")
            return built
        finally:
            self.depth -= 1


def decode(data: bytes) -> Any:
    """What :func:`encode` encoded; anything that is not its output is refused.

    Args:
        data: the bytes (untrusted: a worker runs the env's code).

    Returns:
        The value.

    Raises:
        IsolationError: a record asks for more than it carries, or for what the wire never builds
            (:class:`~hub_envs.errors.AnswerTooLargeError`: it would build far more than it weighs).
        ValueError: the bytes are no message at all (also ``TypeError`` and ``msgpack``'s errors).

    >>> decode(encode((1, {2: b"x"}, frozenset({3}))))
    (1, {2: b'x'}, frozenset({3}))
    >>> decode(b"\\x92\\xa2ok\\xdd\\x7f\\xff\\xff\\xff")  # a list of 2**31 items, announced in 5 bytes  # doctest: +IGNORE_EXCEPTION_DETAIL
    Traceback (most recent call last):
    ValueError: 2147483647 exceeds max_array_len(9)
    """
    decoder = _Decoder(len(data))
    _ACTIVE.decoder = decoder
    try:
        return decoder.load(data)
    except RecursionError:
        raise _refuse("nests values too deep") from None
    finally:
        _ACTIVE.decoder = None


def _charge(nbytes: int, what: str) -> None:
    """Charge the answer being decoded in this thread (records decoded without their decoder)."""
    dec = getattr(_ACTIVE, "decoder", None)
    if dec is not None:
        dec.charge(nbytes, what)
