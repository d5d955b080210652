"""The messages between a parent and its env worker: pickled requests, answers as :mod:`~hub_envs.isolation.wire`
data (never a pickle), the fast step layouts, and env errors rebuilt from their text (``docs/isolation.md``).

Example:
    >>> import numpy as np
    >>> status, value = decode_answer(encode_answer("ok", {"x": np.arange(3, dtype=np.float32), "ok": True}))
    >>> status, value["x"].dtype
    ('ok', dtype('float32'))
"""

from __future__ import annotations

import builtins
import pickle
import struct
from typing import Any

from hub_envs.errors import RemoteEnvError
from hub_envs.isolation.wire import decode, encode

PROTOCOL = 5
#: the longest answer the parent reads from a worker (a longer one stops the worker: EnvCrashedError)
MAX_MESSAGE_BYTES = 1 << 30
#: the head of a fast step request: kind (b"s" single env, b"v" vector slice), the parent's CPU (-1: none; -2: the
#: parent busy-waits, :data:`~hub_envs.isolation.doorbell.SPINNING`)
FAST_HEADER = struct.Struct("<ci")
#: the answer to a single env's fast step when the observation went through shared memory, the reward is a
#: ``float`` and both flags ``bool`` (else the answer is the encoded ``["ok", ...]``): ``b"F"``, reward, terminated,
#: truncated, then the info dict encoded (a parent often gets the same info bytes step after step: see
#: :class:`InfoDecoder`)
FAST_ANSWER = struct.Struct("<cd??")
#: the answer to a vector slice's step when its observations went through shared memory (see :func:`vector_answer`)
VECTOR_ANSWER = struct.Struct("<cI")
#: the info values :class:`InfoDecoder` may hand out again (immutable: a fresh dict of them is a fresh decoding)
_PLAIN = (bool, int, float, str, type(None))


def dumps(obj: Any) -> bytes:
    """A request as the parent sends it (a pickle: the worker trusts its parent).

    Args:
        obj: ``(op, *args)``, or the init dict.

    Returns:
        Its bytes.
    """
    return pickle.dumps(obj, protocol=PROTOCOL)


def encode_answer(status: str, value: Any) -> bytes:
    """A worker's answer on the wire (:mod:`~hub_envs.isolation.wire`).

    Args:
        status: "ok", "err" (the env raised; ``value`` is :func:`error_info`'s) or "fatal" (the worker stops).
        value: what the call returned, or the error.

    Returns:
        Its bytes.

    Raises:
        Unsendable: ``value`` holds something the wire cannot carry.
    """
    return encode([status, value])


def decode_answer(data: bytes) -> tuple[str, Any]:
    """Read a worker's answer.

    Args:
        data: the answer's bytes (untrusted: the worker runs the env's code).

    Returns:
        ``(status, value)`` as :func:`encode_answer` took them.

    Raises:
        ValueError: the bytes are not an answer (see :func:`~hub_envs.isolation.wire.decode`).
        AnswerTooLargeError: decoding them would build far more than they weigh.

    >>> decode_answer(encode_answer("ok", (1.0, {"is_success": True})))
    ('ok', (1.0, {'is_success': True}))
    >>> try:  # a pickle is not an answer
    ...     decode_answer(dumps(("ok", 1)))
    ... except ValueError as e:
    ...     print(type(e).__name__)
    ExtraData
    """
    answer = decode(data)
    if type(answer) is not list or len(answer) != 2 or answer[0] not in ("ok", "err", "fatal"):
        raise ValueError(f"an answer of type {type(answer).__name__}")
    status, value = answer
    if status != "ok" and type(value) is not dict:
        raise ValueError(f"a {status!r} answer whose value is a {type(value).__name__}")
    return status, value


def vector_answer(rewards: Any, terminations: Any, truncations: Any, infos: list) -> bytes:
    """The :data:`VECTOR_ANSWER` of a vector slice's step whose observations went through shared memory.

    Args:
        rewards: float64 array, one per env.
        terminations: bool array.
        truncations: bool array.
        infos: one dict per env.

    Returns:
        ``b"V"``, the number of envs, the rewards, terminations and truncations as raw bytes, then the infos encoded.
    """
    n = len(infos)
    return b"".join(
        (VECTOR_ANSWER.pack(b"V", n), rewards.tobytes(), terminations.tobytes(), truncations.tobytes(), encode(infos))
    )


def read_vector_answer(data: bytes, infos_of: InfoDecoder) -> tuple:
    """Read a :data:`VECTOR_ANSWER`.

    Args:
        data: the answer's bytes (untrusted).
        infos_of: decodes the infos (it remembers the last ones).

    Returns:
        ``(rewards, terminations, truncations, infos, [])``, the arrays over ``data``.

    Raises:
        ValueError: the bytes are shorter than the envs they announce, or the infos are not a list.

    >>> import numpy as np
    >>> r, te, tr, infos, _ = read_vector_answer(vector_answer(np.ones(2), np.zeros(2, bool), np.ones(2, bool), [{}, {}]), InfoDecoder())
    >>> r.tolist(), te.tolist(), tr.tolist(), infos
    ([1.0, 1.0], [False, False], [True, True], [{}, {}])
    """
    import numpy as np

    _, n = VECTOR_ANSWER.unpack_from(data)
    start = VECTOR_ANSWER.size
    if len(data) < start + 10 * n:
        raise ValueError(f"a vector answer for {n:,} envs of {len(data):,} bytes")
    rewards = np.frombuffer(data, np.float64, n, start)
    terminations = np.frombuffer(data, np.bool_, n, start + 8 * n)
    truncations = np.frombuffer(data, np.bool_, n, start + 9 * n)
    infos = infos_of(data[start + 10 * n :])
    if type(infos) is not list:
        raise ValueError("a vector answer whose infos are not a list")
    return rewards, terminations, truncations, infos, []


def fast_answer(reward: Any, terminated: Any, truncated: Any, info: Any) -> bytes | None:
    """The :data:`FAST_ANSWER` of a single env's step whose observation went through shared memory.

    Args:
        reward: the step's reward.
        terminated: its flag.
        truncated: its flag.
        info: its info dict.

    Returns:
        The answer's bytes, or None when these values would not come back as exactly these types that way (a
        reward that is not a ``float``, flags that are not ``bool``): the caller encodes the whole answer instead.

    Raises:
        Unsendable: the info holds something the wire cannot carry.
    """
    if type(reward) is float and type(terminated) is bool and type(truncated) is bool and type(info) is dict:
        return FAST_ANSWER.pack(b"F", reward, terminated, truncated) + encode(info)
    return None


class InfoDecoder:
    """Decodes the infos of :data:`FAST_ANSWER` and :data:`VECTOR_ANSWER` answers (a dict, or a list of dicts, with
    :func:`~hub_envs.isolation.wire.decode`), skipping the decoding when the bytes are those of the last infos and
    they held only str keys and builtin scalars (fresh dicts of the same immutable values are then exactly what
    decoding would give).

    >>> info_of = InfoDecoder()
    >>> a = info_of(encode({"is_success": False}))
    >>> b = info_of(encode({"is_success": False}))
    >>> a == b == {"is_success": False} and a is not b
    True
    >>> info_of(encode([{}, {"x": 1}])) == info_of(encode([{}, {"x": 1}])) == [{}, {"x": 1}]
    True
    """

    def __init__(self) -> None:
        self._bytes: bytes | None = None
        self._infos: list[dict] = []
        self._one = True

    def __call__(self, data: bytes) -> dict | list[dict]:
        if data == self._bytes:
            return dict(self._infos[0]) if self._one else [dict(i) for i in self._infos]
        infos = decode(data)
        one = type(infos) is dict
        listed = [infos] if one else infos
        if type(listed) is not list or not all(type(i) is dict for i in listed):
            raise ValueError(f"infos of type {type(infos).__name__} in a fast answer")
        plain = all(type(k) is str and type(v) in _PLAIN for i in listed for k, v in i.items())
        self._bytes, self._infos, self._one = (data, [dict(i) for i in listed], one) if plain else (None, [], one)
        return infos


def error_info(exc: BaseException) -> dict[str, Any]:
    """What the worker sends for an exception.

    Args:
        exc: the exception the env's code raised.

    Returns:
        ``module``, ``qualname``, ``message``, ``args`` (plain ones only) and ``traceback``, as strings.
    """
    import traceback

    def text(s: str) -> str:  # lone surrogates (surrogateescape'd paths) are not UTF-8: escaped
        return s.encode("utf-8", "backslashreplace").decode("utf-8")

    cls = type(exc)
    args: list[Any] = []
    for a in exc.args:  # plain arguments only (exact types: an IntEnum is not), so the parent rebuilds it exactly
        if type(a) in (int, float, bool, type(None)) or (type(a) is str and text(a) == a):
            args.append(a)
        else:
            args = [text(str(exc))]
            break
    return {
        "module": cls.__module__,
        "qualname": cls.__qualname__,
        "message": text(str(exc)),
        "args": args,
        "traceback": text("".join(traceback.format_exception(exc))),
    }


class RemoteTraceback(Exception):
    """Carries the worker's formatted traceback as the ``__cause__`` of a re-raised env error.

    Args:
        tb: the traceback's text.
    """

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
    """The exception the parent raises for an env error its worker reported.

    Args:
        info: what :func:`error_info` sent (untrusted: its text is escaped).
        where: repo@sha, to name in the message.
        call: the call that raised (``step``, ``reset``, ...).

    Returns:
        A :class:`~hub_envs.errors.RemoteEnvError` (for a builtin exception type, a class that is both that and the
        original type), with the remote traceback as its ``__cause__``.
    """
    from hub_envs._text import safe_lines, safe_text

    module, qualname, message = str(info.get("module")), str(info.get("qualname")), str(info.get("message"))
    # the env's own text, escaped: its terminal sequences never reach the caller's terminal
    shown_module, shown_qualname = safe_text(module), safe_text(qualname)
    text = (
        f"{where}: the env raised {shown_qualname}: {safe_lines(message)} (in {call}, inside its worker process; "
        f"remote traceback above)"
    )
    original = getattr(builtins, qualname, None) if module == "builtins" else None
    if isinstance(original, type) and issubclass(original, Exception) and not issubclass(original, (KeyboardInterrupt,)):
        cls = _remote_class(original)
        try:
            args = [safe_text(a) if isinstance(a, str) else a for a in info.get("args", [])]  # OSError's str shows them
            exc = cls(*args) if cls is not RemoteEnvError else RemoteEnvError(text)
        except Exception:
            exc = RemoteEnvError(text)
        exc.args = (text,)
    else:
        exc = RemoteEnvError(text.replace(f"raised {shown_qualname}", f"raised {shown_module}.{shown_qualname}", 1))
    exc.remote_type = f"{shown_module}.{shown_qualname}"
    exc.remote_traceback = safe_lines(info.get("traceback", ""))
    exc.__cause__ = RemoteTraceback(exc.remote_traceback)
    return exc
