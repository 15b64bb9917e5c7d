"""Typed front for numba's ``njit``, with a compile cache that follows the source.

The 7 kHz controller and the plant step are compiled: under numpy alone one simulated second
costs more than one wall second. ``cache=True`` keeps the machine code on disk so a second
process starts in well under a second instead of recompiling.

Numba's cache checks only the file of the function it compiles: a compiled loop that inlines
the controller would keep running stale controller code after an edit. So the cache lives
in a folder named after a hash of every source file of this package; any edit starts a fresh
cache. ``NUMBA_CACHE_DIR`` set by the user wins. ``NUMBA_DISABLE_JIT=1`` runs everything as
plain Python (for debugging and coverage).
"""

import hashlib
import inspect
import os
import shutil
import time
import types
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar, cast


def _source_hash() -> str:
    digest = hashlib.sha256()
    package = Path(__file__).resolve().parent
    for path in sorted(package.rglob("*.py")):
        digest.update(path.relative_to(package).as_posix().encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def _cache_dir() -> str:
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return str(base / "ankle-telerehab" / f"numba-{_source_hash()}")


STALE_S = 7 * 24 * 3600.0
"""A cache of other sources unused this long is dropped. Others are kept: two checkouts of
different sources on one machine (two branches, or several people's) each keep their own,
rather than each start deleting the other's and compiling again."""


def _last_used(cache: Path) -> float:
    try:
        return max((p.stat().st_mtime for p in cache.iterdir()), default=cache.stat().st_mtime)
    except OSError:  # removed meanwhile
        return 0.0


def _prune(current: str) -> None:
    """Drop the caches of earlier sources (each is tens of MB) once they are stale."""
    here = Path(current)
    if here.exists():
        return
    now = time.time()
    for old in here.parent.glob("numba-*"):
        if now - _last_used(old) > STALE_S:
            shutil.rmtree(old, ignore_errors=True)


if "NUMBA_CACHE_DIR" not in os.environ:
    os.environ["NUMBA_CACHE_DIR"] = _cache_dir()
    _prune(os.environ["NUMBA_CACHE_DIR"])

import numba  # noqa: E402  (reads NUMBA_CACHE_DIR when first imported)
import numba.extending  # noqa: E402

numba.config.CACHE_DIR = os.environ["NUMBA_CACHE_DIR"]  # type: ignore[attr-defined]

_INLINE_SOURCES = frozenset(
    {
        "1052507e1b16a791d6c17efbf0c0ef1efb22e66cb577c78cecb49a58ad584f07",  # numba 0.68.1
    }
)
"""SHA-256 of the source of numba's ``InlineWorker.inline_function`` and ``inline_ir``, as
read for :func:`_inline_without_copies`."""


def _inline_without_copies() -> bool:
    """Spare numba two needless deep copies of every function it inlines; whether it did.

    To inline a call to an ``inline="always"`` function, numba's untyped pass calls
    ``InlineWorker.inline_function``, which builds the callee's IR afresh for that call site
    and hands it to ``inline_ir``. ``inline_ir`` deep-copies it twice, block by block (once
    to work on, once to return unchanged), and each block's copy copies the function's whole
    scope, every variable in it: quadratic in the function's size. In a cold compile of the
    simulated loop that was 57 of 147 CPU seconds, 39 of them for ``controller_tick`` (1,084
    blocks). Here the copies protect nothing:
    the IR is built for this one call and dropped after it, and the pass that calls
    ``inline_function`` ignores the unchanged copy it returns. (Upstream: numba issue 8989.)

    So ``inline_function`` runs with ``copy.deepcopy`` in numba's inlining module returning
    its argument. Nothing else there deep-copies, numba compiles under one global lock, and
    ``inline_ir`` called by other paths (typed inlining of overloads, whose IR numba keeps
    and reuses) still copies. Only applied to the numba source it was read against (the
    hash above): another version compiles the same code, more slowly.

    Measured on the simulated service's cold start: 158 CPU seconds and 5.2 GB at most
    without, 87 s and 2.1 GB with; with a fixed ``PYTHONHASHSEED`` the 80 functions it
    caches came out byte for byte the same (but for the addresses in their comments)."""
    from numba.core import inline_closurecall as module

    inlining: Any = module  # untyped: its ``copy`` is swapped below
    worker: Any = inlining.InlineWorker
    try:
        source = inspect.getsource(worker.inline_function) + inspect.getsource(worker.inline_ir)
    except (OSError, TypeError):  # installed without its sources
        return False
    if hashlib.sha256(source.encode()).hexdigest() not in _INLINE_SOURCES:
        return False
    original = worker.inline_function
    no_copy = types.SimpleNamespace(deepcopy=lambda obj, memo=None: obj)

    def inline_function(self: Any, *args: Any, **kwargs: Any) -> Any:
        outer = inlining.copy  # a nested inlining leaves it as it found it
        inlining.copy = no_copy
        try:
            return original(self, *args, **kwargs)
        finally:
            inlining.copy = outer

    worker.inline_function = inline_function
    return True


INLINE_WITHOUT_COPIES = _inline_without_copies()

F = TypeVar("F", bound=Callable[..., Any])
T = TypeVar("T")


def njit(fn: F) -> F:
    """Compile ``fn`` in nopython mode, cached on disk, releasing the GIL."""
    return cast(F, numba.njit(cache=True, nogil=True)(fn))


def njit_inline(fn: F) -> F:
    """As :func:`njit`, and inlined into compiled callers.

    For the functions called once per tick from the fused loop: a call that is not inlined
    increments and decrements the reference count of every array in the state tuples it
    receives, which costs more than the work of a quiet tick. Inlining alone does not always
    save that: numba increments every array of a tuple bound to an inlined function's
    argument too, and removes the pair again only when nothing branches between them (with
    ``perf``, 76 % of the simulated loop's time was those atomic increments and decrements).
    A helper run every tick that branches should take the arrays it uses, not the tuples.
    The simulated loop (``device.tickloop.run_sim``) works on :data:`unowned` views of its
    state, where nothing is counted at all.

    It costs compile time: numba compiles such a function by itself to type its call, then
    copies its IR into each caller. ``controller_tick`` called plainly from ``run_sim``
    took a cold compile from 153 s to 108 s, and the loop from 68 to 51 simulated seconds
    per CPU second (best of 30 windows): kept inlined.
    """
    return cast(F, numba.njit(cache=True, nogil=True, inline="always")(fn))


def _unowned_value(context: Any, builder: Any, ty: Any, value: Any) -> Any:
    """Lower one member of :func:`unowned`'s argument (recursing into tuples)."""
    types: Any = numba.core.types  # untyped: its classes must not narrow ``ty``
    if isinstance(ty, types.Array):
        src = context.make_array(ty)(context, builder, value=value)
        out = context.make_array(ty)(context, builder)
        for name in ("nitems", "itemsize", "data", "shape", "strides"):
            setattr(out, name, getattr(src, name))
        out.meminfo = context.get_constant_null(types.MemInfoPointer(ty.dtype))
        out.parent = context.get_constant_null(types.pyobject)
        return out._getvalue()
    if isinstance(ty, types.BaseTuple):
        members = [
            _unowned_value(context, builder, t, builder.extract_value(value, i))
            for i, t in enumerate(ty.types)
        ]
        return context.make_tuple(builder, ty, members)
    context.nrt.incref(builder, ty, value)  # returned: a reference of its own
    return value


def _unowned(typingctx: Any, state: Any) -> Any:
    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        return _unowned_value(context, builder, signature.args[0], args[0])

    return state(state), codegen


def _as_identity(intrinsic: Any) -> Callable[[T], T]:
    return cast(Callable[[T], T], intrinsic)


unowned = _as_identity(numba.extending.intrinsic(_unowned))
"""``unowned(state)``, in compiled code only: ``state`` (an array or a tuple of them, nested
or not) with every array's reference to its owner dropped: the same data, shape and type,
but nothing to count.

Inside a compiled loop numba raises and lowers the reference count of every array a variable
holds, and binding a tuple of arrays to a function's argument, inlined or not, counts all of
its arrays; numba removes such pairs only where no other decrement lies between them. Over
the simulated loop that was 158 atomic increments and 160 decrements a tick. On arrays
without an owner they are operations on nothing, which numba's pruning drops.

Only for a caller that keeps ``state`` itself alive for as long as the result is used (its
own argument) and never hands an array of the result to Python or stores it."""


def typed_entry(fn: F, *args: object) -> F:
    """``fn`` compiled (or loaded from the cache) for exactly the types of ``args``, as a
    function that skips the dispatcher's resolution of its arguments' types at every call.

    Called from Python once a tick, that resolution is most of a call's cost: 16 of the
    22 us a call of the plant's tick took, for its tuples of 23 and 73 fields. The result
    must only ever get arguments of those same types: it does not convert or refuse others,
    it misreads them. Under ``NUMBA_DISABLE_JIT=1``, ``fn`` itself."""
    if not isinstance(fn, numba.core.dispatcher.Dispatcher):
        return fn
    typeof: Any = numba.typeof  # untyped
    return cast(F, fn.compile(tuple(typeof(a) for a in args)))
