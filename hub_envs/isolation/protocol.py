"""The wire between a parent and an env worker: framed pickles over a socketpair, and what may come back.

* Parent -> worker: ``pickle`` of a tuple ``(op, *args)`` (the parent is trusted by the worker), or, for
  the step of a Box-action env (the hot path), :data:`FAST_HEADER` (``b"s"``: a single env, ``b"v"``: a
  vector slice; the CPU the parent waits on, see :mod:`~hub_envs.isolation.affinity`) and the raw action bytes.
* Worker -> parent: ``("ok", value)``, ``("err", ErrorInfo-dict)`` (the env raised: the worker lives on) or
  ``("fatal", ErrorInfo-dict)`` (the worker cannot go on, e.g. MemoryError: it exits after sending); the answer to
  a single env's fast step whose observation went through shared memory may instead be a :data:`FAST_ANSWER`.

What the worker sends is read with :class:`SafeUnpickler`, which builds only plain data, numpy arrays and
scalars and gymnasium spaces: unpickling anything else would let the env's code (which may be sandboxed,
and is never trusted more than it was in-process) run code in the parent. Nor may a few bytes make the parent
build gigabytes (``bytearray(10**11)``, ``set(range(10**10))``, ``Box(0, 1, (10**5, 10**5))``): decoding happens
after the watchdog, so the containers that can be called to build something big are charged against a budget of
the answer's size (:class:`_Guarded`), other types are never called (:class:`_CarefulUnpickler`) and numpy's
pickling functions are checked (:func:`_numpy_guard`). Holes that remain (a memo index, deep nesting, a random
generator's state) need a wire format other than pickle. Exceptions therefore never travel as objects: the
worker sends the type's name, its message and the formatted traceback, and :func:`rebuild_error` raises a :class:`~hub_envs.errors.RemoteEnvError` (for builtin exception types, a
class that is both that and the original type, so ``except ValueError`` keeps working).

Example:
    >>> import pickle, numpy as np
    >>> from hub_envs.isolation.protocol import safe_loads
    >>> safe_loads(pickle.dumps({"x": np.arange(3, dtype=np.float32), "ok": True}, protocol=5))["x"].dtype
    dtype('float32')
    >>> import os
    >>> safe_loads(pickle.dumps(os.getcwd))  # doctest: +IGNORE_EXCEPTION_DETAIL
    Traceback (most recent call last):
    hub_envs.errors.IsolationError: ...
"""

from __future__ import annotations

import builtins
import collections
import io
import pickle
import struct
import sys
from typing import Any

from hub_envs.errors import IsolationError, RemoteEnvError

PROTOCOL = 5
#: the longest answer the parent reads from a worker (a longer one stops the worker: EnvCrashedError)
MAX_MESSAGE_BYTES = 1 << 30
#: the head of a fast step request: kind (b"s" single env, b"v" vector slice), the parent's CPU (-1: none; -2: the
#: parent busy-waits, :data:`~hub_envs.isolation.doorbell.SPINNING`)
FAST_HEADER = struct.Struct("<ci")
#: the answer to a single env's fast step when the observation went through shared memory, the reward is a
#: ``float`` and both flags ``bool`` (else the answer is the pickled ``("ok", ...)``): ``b"F"``, reward, terminated,
#: truncated, then the info dict pickled (a parent often gets the same info bytes step after step: see
#: :class:`InfoDecoder`)
FAST_ANSWER = struct.Struct("<cd??")
#: the info values :class:`InfoDecoder` may hand out again (immutable: a fresh dict of them is a fresh unpickling)
_PLAIN = (bool, int, float, str, type(None))

_NUMPY_NAMES = {
    "_reconstruct",
    "scalar",
    "_frombuffer",
    "ndarray",
    "dtype",
    "__generator_ctor",
    "__bit_generator_ctor",
    "__randomstate_ctor",
    "_DType_reconstruct",
}
_BUILTINS = {
    "set",
    "frozenset",
    "slice",
    "complex",
    "range",
    "bytearray",
    "bytes",
    "list",
    "dict",
    "tuple",
    "int",
    "float",
    "bool",
    "str",
}


#: the numpy modules a worker's answer may name (what numpy's own pickles use); no other module is ever imported
_NUMPY_MODULES = {
    "numpy",
    "numpy.dtypes",
    "numpy._core.multiarray",
    "numpy.core.multiarray",
    "numpy._core.numeric",
    "numpy.core.numeric",
    "numpy.random",
    "numpy.random._pickle",
    "numpy.random.bit_generator",
    "numpy.random._pcg64",
    "numpy.random._mt19937",
    "numpy.random._philox",
    "numpy.random._sfc64",
    "numpy.random._generator",
    "numpy.random.mtrand",
}


def _allowed(module: str, name: str) -> bool:
    if "." in name:
        return False
    if module == "builtins":
        return name in _BUILTINS
    if module == "collections":
        return name in ("OrderedDict", "defaultdict", "deque")
    if module in _NUMPY_MODULES:
        if name in _NUMPY_NAMES or name.endswith("DType"):
            return True
        if module == "numpy":  # scalar types (numpy.float32, numpy.bool, ...)
            import numpy as np

            obj = getattr(np, name, None)
            return isinstance(obj, type) and issubclass(obj, np.generic)
        if module.startswith("numpy.random"):  # bit generators (PCG64, MT19937, ...) and their seed sequences
            return name.startswith("__pyx_unpickle_SeedSequence") or name in (
                "SeedSequence",
                "PCG64",
                "PCG64DXSM",
                "MT19937",
                "Philox",
                "SFC64",
                "Generator",
                "RandomState",
            )
        return False
    if module.startswith("gymnasium.spaces") and module in sys.modules:  # loaded with gymnasium; never imported here
        import gymnasium.spaces as spaces

        obj = getattr(spaces, name, None)
        return isinstance(obj, type) and issubclass(obj, spaces.Space)
    return False


def _refuse(what: str) -> IsolationError:
    return IsolationError(
        f"the env worker sent an answer that {what}, which an isolated env may not have the parent do. Return plain "
        f"data from the env."
    )


def _checked_dtype(dtype: Any) -> Any:
    """``dtype`` if it is what numpy itself would build from its fields (a dtype's pickled state can claim fields
    its flags deny: object pointers read from raw bytes, offsets past the item), else IsolationError."""
    import numpy as np

    if not isinstance(dtype, np.dtype):
        return dtype
    if dtype.fields is not None:
        try:
            names = list(dtype.names)
            rebuilt = np.dtype(
                {
                    "names": names,
                    "formats": [_checked_dtype(dtype.fields[n][0]) for n in names],
                    "offsets": [dtype.fields[n][1] for n in names],
                    "itemsize": dtype.itemsize,
                }
            )
        except (TypeError, ValueError) as e:
            raise _refuse(f"holds a malformed structured dtype ({e})") from None
        if rebuilt != dtype or rebuilt.hasobject != dtype.hasobject or rebuilt.flags != dtype.flags:
            raise _refuse("holds a structured dtype whose state contradicts its fields")
    elif dtype.subdtype is not None:
        _checked_dtype(dtype.subdtype[0])
    return dtype


def _numpy_guard(name: str, real: Any) -> Any:
    """numpy's pickling functions, checked: each may build only what numpy's own pickles ask of it."""
    import numpy as np

    if name == "_reconstruct":  # numpy pickles (ndarray, (0,), b"b"): an empty array its state then fills

        def reconstruct(subtype, shape, dtype):
            if subtype is not np.ndarray or tuple(shape) != (0,):
                raise _refuse(f"asks numpy to allocate an array of shape {shape!r} before its data")
            return real(subtype, shape, _checked_dtype(dtype))

        return reconstruct
    if name == "scalar":  # (dtype, its bytes)

        def scalar(dtype, *obj):
            dtype = _checked_dtype(dtype)
            if not obj or (not dtype.hasobject and (type(obj[0]) is not bytes or len(obj[0]) != dtype.itemsize)):
                raise _refuse(f"asks numpy for a scalar of {dtype.itemsize} bytes without those bytes")
            return real(dtype, *obj)

        return scalar
    if name == "_frombuffer":  # (bytes, dtype, shape, order): an array over the bytes sent

        def frombuffer(buf, dtype, *rest):
            dtype = _checked_dtype(dtype)
            if dtype.hasobject:
                raise _refuse("asks numpy to read object pointers from raw bytes")
            return real(buf, dtype, *rest)

        return frombuffer
    if name in ("__generator_ctor", "__bit_generator_ctor", "__randomstate_ctor"):  # (a bit generator or its name)

        def ctor(*args):
            for a in args:
                ok = isinstance(a, (str, np.random.BitGenerator)) or (
                    isinstance(a, type) and issubclass(a, np.random.BitGenerator)
                )
                if not ok:
                    raise _refuse(f"calls numpy's {name} with a {type(a).__name__}")
            return real(*args)

        return ctor
    return real


#: allowed types whose *call* can build far more than the pickle that asks for it (``bytearray(10**11)``: 30 bytes
#: of pickle, 100 GB zeroed; ``set(range(10**10))``): the unpickler hands out a :class:`_Guarded` stand-in for them
_AMPLIFIERS = {("builtins", n) for n in ("set", "frozenset", "list", "tuple", "bytes", "bytearray")} | {("collections", "deque")}
#: what the guarded calls of one answer may build in all (items or bytes): this many per byte of the answer, plus
#: :data:`_BUDGET_FLOOR` (an honest protocol-5 pickle calls them only for a ``deque``, one item per item it holds)
_BUDGET_PER_BYTE = 8
_BUDGET_FLOOR = 1 << 20


class _Guarded:
    """Stands in for an amplifying type during one load: a call is charged to the load's budget first (its argument's
    length, or the size asked of ``bytes``/``bytearray``), and an argument whose length is not known (an iterator) is
    refused. Where the pickle used the type as a value (``defaultdict(list)``), :func:`_unguard` puts it back."""

    __slots__ = ("real", "owner")

    def __init__(self, real: type, owner: _AllowList):
        self.real, self.owner = real, owner

    def __call__(self, *args, **kwargs):
        cost = 0
        if args:
            first = args[0]
            if isinstance(first, int) and self.real in (bytes, bytearray):
                cost = first
            else:
                try:
                    # bytes(array) copies the array's bytes, whatever its len(); the others build len() items
                    cost = memoryview(first).nbytes if self.real in (bytes, bytearray) else len(first)
                except TypeError:
                    try:
                        cost = len(first)
                    except (TypeError, OverflowError):
                        cost = -1
                except OverflowError:
                    cost = -1
        if cost < 0 or cost > self.owner.budget:
            raise IsolationError(
                f"the env worker sent an answer that builds a {self.real.__name__} of "
                f"{'unknown size' if cost < 0 else f'{cost:,} items'} from a {self.owner.size:,}-byte message (more than "
                f"an answer of that size may build). Return the data itself from the env, not a recipe for it."
            )
        self.owner.budget -= cost
        return self.real(*args, **kwargs)


def _unguard(obj: Any, seen: dict[int, Any]) -> Any:
    """``obj`` with every :class:`_Guarded` in it (containers walked, cycles kept) replaced by its real type."""
    if type(obj) is _Guarded:
        return obj.real
    key = id(obj)
    if key in seen:
        return seen[key]
    kind = type(obj)
    if kind in (list, collections.deque):
        seen[key] = obj
        for i, item in enumerate(obj):
            obj[i] = _unguard(item, seen)
    elif kind in (dict, collections.OrderedDict, collections.defaultdict):
        seen[key] = obj
        if kind is collections.defaultdict:
            obj.default_factory = _unguard(obj.default_factory, seen)
        items = [(_unguard(k, seen), _unguard(v, seen)) for k, v in obj.items()]
        obj.clear()
        obj.update(items)
    elif kind in (tuple, set, frozenset):
        seen[key] = obj
        seen[key] = obj = kind(_unguard(item, seen) for item in obj)
    return obj


def _callable_type(found: type) -> bool:
    """Whether a pickle may call this (allowed) type to build a value: cheap for any arguments (numpy's ``dtype`` is
    how dtypes are pickled), or charged (:class:`_Guarded`). The others (gymnasium spaces, ``numpy.ndarray``, numpy's
    scalar and random types, ...) may only be values, or be built by ``__new__`` and their state as pickle builds
    objects: calling one runs its ``__init__`` on the sender's arguments (``Box(0, 1, (10**5, 10**5))`` fills 80 GB)."""
    if found in (range, slice, complex, int, float, bool, str, collections.OrderedDict, collections.defaultdict):
        return True
    return found.__module__.startswith("numpy") and found.__name__ == "dtype"


class _Rescan(Exception):
    """The fast (C) unpickler met a type it cannot keep from being called: decode again with :class:`_CarefulUnpickler`."""


class _AllowList:
    """What both unpicklers share: the allow-list, the guarded types, the budget, the types put back after loading."""

    careful = False

    def __init__(self, data: bytes):
        super().__init__(io.BytesIO(data))
        self.size = len(data)
        self.budget = _BUDGET_PER_BYTE * self.size + _BUDGET_FLOOR
        self.guarded = False

    def find_class(self, module: str, name: str):
        if _allowed(module, name):
            found = super().find_class(module, name)
            if module in _NUMPY_MODULES and name in _NUMPY_NAMES:
                found = _numpy_guard(name, found)
            if (module, name) in _AMPLIFIERS:
                self.guarded = True
                return _Guarded(found, self)
            if isinstance(found, type) and not self.careful and not _callable_type(found):
                raise _Rescan
            return found
        raise IsolationError(
            f"the env worker sent an object of type {module}.{name}, which an isolated env may not hand to the parent "
            f"(only numbers, strings, lists/dicts, numpy arrays and gymnasium spaces). Return plain data from the env."
        )

    def load(self) -> Any:
        obj = super().load()
        return _unguard(obj, {}) if self.guarded else obj


class SafeUnpickler(_AllowList, pickle.Unpickler):
    """The allow-list unpickler (see the module docstring): builds only data; anything else is an IsolationError, and
    so is an answer that asks an allowed type to build much more than the answer's own size (:class:`_Guarded`).
    The C unpickler, for the usual answers; one holding a type that must not be called (a gymnasium space, a random
    generator's state, ...) raises :class:`_Rescan` for :class:`_CarefulUnpickler`."""


class _CarefulUnpickler(_AllowList, pickle._Unpickler):
    """The pure-Python unpickler with the same allow-list, whose ``REDUCE`` refuses to call a type that
    :func:`_callable_type` does not allow (slower: answers that hold such types are rare, e.g. an env's spaces)."""

    careful = True
    dispatch = dict(pickle._Unpickler.dispatch)

    def load_reduce(self) -> None:
        args = self.stack.pop()
        func = self.stack[-1]
        if isinstance(func, type) and not _callable_type(func):  # a value it may send, not one to build here
            raise _refuse(f"has the parent call {func.__module__}.{func.__qualname__}(...)")
        self.stack[-1] = func(*args)

    dispatch[pickle.REDUCE[0]] = load_reduce

    def load_newobj(self) -> None:
        args = self.stack.pop()
        cls = self.stack.pop()
        if args:  # honest pickles (spaces) create the object empty and then set its state
            raise _refuse(f"creates a {getattr(cls, '__qualname__', cls)} from arguments")
        self.append(cls.__new__(cls))

    dispatch[pickle.NEWOBJ[0]] = load_newobj

    def load_newobj_ex(self) -> None:
        kwargs = self.stack.pop()
        args = self.stack.pop()
        cls = self.stack.pop()
        if args or kwargs:
            raise _refuse(f"creates a {getattr(cls, '__qualname__', cls)} from arguments")
        self.append(cls.__new__(cls))

    dispatch[pickle.NEWOBJ_EX[0]] = load_newobj_ex

    def _refused_opcode(self) -> None:  # INST, OBJ: protocol 0/1 ways to call a class; protocol 5 never uses them
        raise _refuse("calls a class the protocol-0 way (INST/OBJ)")

    dispatch[pickle.INST[0]] = _refused_opcode
    dispatch[pickle.OBJ[0]] = _refused_opcode


def dumps(obj: Any) -> bytes:
    return pickle.dumps(obj, protocol=PROTOCOL)


def safe_loads(data: bytes) -> Any:
    """Unpickle what a worker sent with :class:`SafeUnpickler`.

    >>> from collections import defaultdict, deque
    >>> safe_loads(dumps({"q": deque([1, 2], maxlen=3), "d": defaultdict(list, a=[1])}))
    {'q': deque([1, 2], maxlen=3), 'd': defaultdict(<class 'list'>, {'a': [1]})}
    >>> class Recipe:
    ...     def __reduce__(self):
    ...         return (bytearray, (10**11,))
    >>> safe_loads(dumps(Recipe()))  # doctest: +IGNORE_EXCEPTION_DETAIL
    Traceback (most recent call last):
    hub_envs.errors.IsolationError: ...builds a bytearray of 100,000,000,000 items from a 36-byte message...
    >>> import gymnasium as gym
    >>> safe_loads(dumps(gym.spaces.Box(0.0, 1.0, (2,))))  # a type that must not be called: the careful decoder
    Box(0.0, 1.0, (2,), float32)
    """
    try:
        try:
            return SafeUnpickler(data).load()
        except _Rescan:
            return _CarefulUnpickler(data).load()
    except SystemExit as e:  # nothing decoding plain data raises it: never let an answer end the parent
        raise _refuse(f"raised SystemExit({e}) while it was decoded") from None


def fast_answer(reward: Any, terminated: Any, truncated: Any, info: Any) -> bytes | None:
    """The :data:`FAST_ANSWER` of a step whose observation went through shared memory, or None when its values
    would not come back as exactly these types that way (the caller pickles the answer instead)."""
    if type(reward) is float and type(terminated) is bool and type(truncated) is bool and type(info) is dict:
        return FAST_ANSWER.pack(b"F", reward, terminated, truncated) + dumps(info)
    return None


class InfoDecoder:
    """Decodes the info of :data:`FAST_ANSWER` answers with :func:`safe_loads`, skipping the unpickling when the
    bytes are those of the last info and it held only str keys and builtin scalars (a fresh dict of the same
    immutable values is then exactly what unpickling would give).

    >>> decode = InfoDecoder()
    >>> a = decode(dumps({"is_success": False}))
    >>> b = decode(dumps({"is_success": False}))
    >>> a == b == {"is_success": False} and a is not b
    True
    """

    def __init__(self) -> None:
        self._bytes: bytes | None = None
        self._info: dict = {}

    def __call__(self, data: bytes) -> dict:
        if data == self._bytes:
            return dict(self._info)
        info = safe_loads(data)
        if type(info) is not dict:
            raise ValueError(f"an info of type {type(info).__name__} in a fast answer")
        plain = all(type(k) is str and type(v) in _PLAIN for k, v in info.items())
        self._bytes, self._info = (data, dict(info)) if plain else (None, {})
        return info


def error_info(exc: BaseException) -> dict[str, Any]:
    """What the worker sends for an exception: type, message and formatted traceback (all strings)."""
    import traceback

    cls = type(exc)
    args: list[Any] = []
    for a in exc.args:  # plain arguments only, so the parent can rebuild a builtin exception exactly
        if isinstance(a, (str, int, float, bool, type(None))):
            args.append(a)
        else:
            args = [str(exc)]
            break
    return {
        "module": cls.__module__,
        "qualname": cls.__qualname__,
        "message": str(exc),
        "args": args,
        "traceback": "".join(traceback.format_exception(exc)),
    }


class RemoteTraceback(Exception):
    """Carries the worker's formatted traceback as the ``__cause__`` of a re-raised env error."""

    def __init__(self, tb: str):
        super().__init__(tb)
        self.tb = tb

    def __str__(self) -> str:
        return f'\n"""\n{self.tb}"""'


_REMOTE_CLASSES: dict[type, type] = {}


def _remote_class(original: type) -> type:
    cls = _REMOTE_CLASSES.get(original)
    if cls is None:
        try:
            cls = type(original.__name__, (RemoteEnvError, original), {"__module__": "hub_envs.errors"})
        except TypeError:  # an instance layout RemoteEnvError cannot share
            cls = RemoteEnvError
        _REMOTE_CLASSES[original] = cls
    return cls


def rebuild_error(info: dict[str, Any], where: str, call: str) -> BaseException:
    """The exception the parent raises for an env error the worker reported in ``call``."""
    module, qualname, message = str(info.get("module")), str(info.get("qualname")), str(info.get("message"))
    text = f"{where}: the env raised {qualname}: {message} (in {call}, inside its worker process; remote traceback above)"
    original = getattr(builtins, qualname, None) if module == "builtins" else None
    if isinstance(original, type) and issubclass(original, Exception) and not issubclass(original, (KeyboardInterrupt,)):
        cls = _remote_class(original)
        try:
            exc = cls(*info.get("args", [])) if cls is not RemoteEnvError else RemoteEnvError(text)
        except Exception:
            exc = RemoteEnvError(text)
        exc.args = (text,)
    else:
        exc = RemoteEnvError(text.replace(f"raised {qualname}", f"raised {module}.{qualname}"))
    exc.remote_type = f"{module}.{qualname}"
    exc.remote_traceback = str(info.get("traceback", ""))
    exc.__cause__ = RemoteTraceback(exc.remote_traceback)
    return exc
