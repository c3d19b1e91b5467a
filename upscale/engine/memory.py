"""What a run keeps in memory: the bytes of the numpy arrays an object graph holds.

:func:`kept_nbytes` walks the attributes of the given objects (instances, dataclasses,
namespaces, tuples, lists, dicts) and sums the bytes of every distinct numpy buffer it
reaches once (views of one buffer count once: a view is charged its base). Arrays
reachable from ``exclude`` are not charged: e.g. pass the system to count a model and its
family without the reference positions and volumes they share with it. Arrays made on
demand (the family's ``xi``, a model's ``bond_weights()``) are not kept and so not
counted; temporaries of a build or of one evaluation are not in the graph either, so the
peak of a run is larger than this figure.

:func:`bytes_per_bond` is the figure the scenes report: the family's and the models'
kept bytes (per-bond and per-particle buffers apart) and the run's bond state, per
directed bond.
"""
from __future__ import annotations

import math
import resource
import sys
from pathlib import Path

import numpy as np

__all__ = ["kept_buffers", "kept_nbytes", "bytes_per_bond", "peak_rss_gb", "run_memory",
           "lattice_bonds", "available_gb", "require_fit"]


def _buffer(a: np.ndarray) -> np.ndarray:
    while isinstance(a.base, np.ndarray):
        a = a.base
    return a


def _walk(obj, seen_obj: set, seen_buf: dict) -> None:
    stack = [obj]
    while stack:
        o = stack.pop()
        if o is None or isinstance(o, (str, bytes, int, float, bool, complex, type)):
            continue
        if id(o) in seen_obj:
            continue
        seen_obj.add(id(o))
        if isinstance(o, np.ndarray):
            if o.dtype != object:
                b = _buffer(o)
                seen_buf[id(b)] = b
                continue
            stack.extend(o.ravel().tolist())
            continue
        if isinstance(o, dict):
            stack.extend(o.values())
        elif isinstance(o, (list, tuple, set, frozenset)):
            stack.extend(o)
        elif hasattr(o, "__dict__") and not callable(o):
            stack.extend(vars(o).values())
        elif hasattr(o, "__slots__"):
            stack.extend(getattr(o, s, None) for s in o.__slots__)


def kept_buffers(*objects, exclude=()) -> list[np.ndarray]:
    """The distinct numpy buffers reachable from ``objects`` and not from ``exclude``."""
    ex_obj: set = set()
    ex_buf: dict = {}
    for e in exclude:
        _walk(e, ex_obj, ex_buf)
    seen_obj = set(ex_obj)
    bufs: dict = {}
    for o in objects:
        _walk(o, seen_obj, bufs)
    return [b for k, b in bufs.items() if k not in ex_buf]


def kept_nbytes(*objects, exclude=()) -> int:
    """Bytes of :func:`kept_buffers` (see the module docstring)."""
    return int(sum(b.nbytes for b in kept_buffers(*objects, exclude=exclude)))


def _per_particle(a: np.ndarray, n: int) -> bool:
    """A buffer of per-particle data: leading dimension N or N + 1, or per-thread
    buffers (T, N, ...)."""
    return a.ndim >= 1 and (a.shape[0] in (n, n + 1) or (a.ndim >= 2 and a.shape[1] == n))


def bytes_per_bond(system, family, models=(), state=None) -> dict:
    """What ``family`` and ``models`` keep (without ``system``'s own arrays), per directed
    bond: ``"bond"`` the buffers that grow with the bonds (every buffer that is not per
    particle, class tables included), ``"particle"`` the per-particle buffers (row
    pointers, per-particle tensors, thread buffers) spread over the bonds, ``"state"`` the
    run's bond state (``state.intact``, 1 byte per bond as bool, and the models' arrays in
    ``state.extra``), ``"total"`` their sum. The per-particle share falls as the horizon
    grows (bonds per particle ~ pi m^2 in 2D)."""
    nb, n = max(int(family.nb), 1), int(family.n)
    bufs = kept_buffers(family, *models, exclude=(system,))
    part = sum(b.nbytes for b in bufs if _per_particle(b, n))
    bond = sum(b.nbytes for b in bufs) - part
    st = 0
    if state is not None:
        st = int(np.asarray(state.intact).nbytes)
        st += sum(v.nbytes for v in state.extra.values() if isinstance(v, np.ndarray))
    return {"bond": bond / nb, "particle": part / nb, "state": st / nb,
            "total": (bond + part + st) / nb}


def peak_rss_gb() -> float:
    """The process's peak resident memory so far (GB, 1e9 bytes): ``ru_maxrss`` (kB on
    Linux, bytes on macOS)."""
    r = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return float(r) / (1e9 if sys.platform == "darwin" else 1e6)


def run_memory(system, family, models=(), state=None) -> dict:
    """A scene's ``meta["memory"]``: its directed bonds, :func:`bytes_per_bond` (kept, not
    streamed) and the process's peak resident memory (GB) when it is called."""
    return {"bonds": int(family.nb),
            "bytes_per_bond": bytes_per_bond(system, family, models, state),
            "peak_rss_GB": peak_rss_gb()}


def lattice_bonds(m: float, dim: int) -> int:
    """Bonds of an interior particle of a square (``dim`` 2) or cubic (3) lattice of
    horizon ``m`` spacings: the lattice points k != 0 with |k| <= m (pi m^2 and 4/3 pi m^3
    for large m; 28 for m = 3.015 in 2D)."""
    r = int(math.floor(m))
    k = np.arange(-r, r + 1)
    g = np.meshgrid(*([k] * int(dim)), indexing="ij")
    return int((sum(a * a for a in g) <= m * m + 1e-9).sum()) - 1


def available_gb() -> float | None:
    """Memory the kernel reports as available to a new allocation (``MemAvailable`` of
    ``/proc/meminfo``, GB); None where it is not known (no check is made then)."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1e3 / 1e9
    except OSError:
        return None
    return None


def require_fit(estimate_gb: float, what: str, largest=None) -> None:
    """Refuse a build whose estimated peak (GB) exceeds :func:`available_gb`, before it
    starts: ``MemoryError`` in one line with the estimate and, given ``largest`` (a
    function of the available GB returning text), the largest size that fits."""
    avail = available_gb()
    if avail is not None and estimate_gb > avail:
        more = f"; the largest that fits: {largest(avail)}" if largest else ""
        raise MemoryError(f"{what} needs about {estimate_gb:.3g} GB at its peak, "
                          f"{avail:.3g} GB available{more}")
