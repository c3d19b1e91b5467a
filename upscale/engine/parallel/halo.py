"""A rank's part of the body: its particles, the halo of partners owned by other ranks,
its rows of the family, and the exchange of halo rows.

Layers. The owned particles' rows are complete. A bond-based force on an owned particle
needs its partners' positions only (one layer of halo). A state-based force (LPS) also
needs each partner's dilatation, a sum over the partner's own row, so the first halo layer
gets complete rows as well and a second layer holds their partners (two layers); the
models then compute the halo's per-particle state themselves from exchanged positions
and need no hook (the work on the first layer's rows is done twice, by the owner and by
this rank). ``depth`` is the number of layers.

Local family. The local particles are kept in the order of their global index, and a
local directed bond is a global bond ``i -> j`` with a complete-row end (``i`` or ``j`` in
the complete-row set). This set is symmetric (the reverse of a kept bond is kept), each
row keeps the global order of its partners, and every pair is seen in the orientation
and the relative order of the serial run: a pair loop over the local family adds each
owned particle's bond terms in the serial order, which is what makes the distributed
forces bit-identical to the serial ones on one thread.

Bond state. A bond between an owned particle and a halo particle lives on both ranks.
Both copies are decided by the same criterion, in the same orientation, from the same
bits (the halo positions are the owner's, copied each step), so they agree without any
message; :func:`bond_states_agree` checks it.
"""
from __future__ import annotations

import dataclasses

import numba as nb
import numpy as np

__all__ = ["Local", "build_local", "build_local_rows", "bond_states_agree"]


@dataclasses.dataclass(eq=False)
class Local:
    """One rank's view: global ids ``gid`` (n_local,) int64 sorted, ``owned`` (n_local,)
    bool, the local CSR family ``offsets`` / ``neighbors``, the global directed index of
    each local bond ``bond_gid``, and the halo exchange lists ``send`` / ``recv``
    (``[(peer rank, local rows)]``, rows in global order on both sides)."""

    rank: int
    size: int
    depth: int
    n_global: int
    nb_global: int
    gid: np.ndarray
    owned: np.ndarray
    offsets: np.ndarray
    neighbors: np.ndarray
    bond_gid: np.ndarray
    send: list
    recv: list
    complete: np.ndarray | None = None  # (n_local,) bool: the rows that are whole

    @property
    def n(self) -> int:
        return self.gid.shape[0]

    @property
    def n_owned(self) -> int:
        return int(np.count_nonzero(self.owned))

    @property
    def owned_bonds(self) -> np.ndarray:
        """(nb_local,) bool: bonds in an owned particle's row (each global directed bond is
        in exactly one rank's owned rows)."""
        return np.repeat(self.owned, np.diff(self.offsets))

    def halo_rows(self) -> int:
        return int(sum(r.shape[0] for _, r in self.recv))

    def exchange(self, comm, a: np.ndarray) -> None:
        """Mutates ``a`` (n_local, ...): the halo rows get their owners' values (one
        nonblocking message per peer and direction)."""
        tail = a.shape[1:]
        sends = [(p, np.ascontiguousarray(a[rows])) for p, rows in self.send]
        recvs = [(p, np.empty((rows.shape[0],) + tail, dtype=a.dtype)) for p, rows in self.recv]
        comm.exchange(sends, recvs)
        for (_, rows), (_, buf) in zip(self.recv, recvs):
            a[rows] = buf

    def gather(self, comm, a: np.ndarray) -> np.ndarray:
        """The global array (n_global, ...) on every rank from each rank's owned rows."""
        a = np.asarray(a)
        parts = comm.allgather((self.gid[self.owned], a[self.owned]))
        out = np.empty((self.n_global,) + a.shape[1:], dtype=a.dtype)
        for g, v in parts:
            out[g] = v
        return out


    def gather_bonds(self, comm, a: np.ndarray) -> np.ndarray:
        """The global per-bond array (nb_global, ...) on every rank from the owned rows."""
        a = np.asarray(a)
        own = self.owned_bonds
        parts = comm.allgather((self.bond_gid[own], a[own]))
        out = np.empty((self.nb_global,) + a.shape[1:], dtype=a.dtype)
        for g, v in parts:
            out[g] = v
        return out


@nb.njit(cache=True)
def _partners(offsets, neighbors, mask_n):
    """(N,) bool: the partners of the particles in ``mask_n``."""
    out = np.zeros(mask_n.shape[0], dtype=np.bool_)
    for i in range(mask_n.shape[0]):
        if mask_n[i]:
            for b in range(offsets[i], offsets[i + 1]):
                out[neighbors[b]] = True
    return out


@nb.njit(cache=True)
def _local_rows(offsets, neighbors, full_n, gid_l, lid_n):
    """The local CSR rows: of each local particle (global ``gid_l``), its global bonds
    with a complete-row end, in the global order. Returns (offsets, local partners,
    global directed index of each local bond)."""
    m = gid_l.shape[0]
    off = np.zeros(m + 1, dtype=np.int64)
    for a in range(m):
        i = gid_l[a]
        c = 0
        for b in range(offsets[i], offsets[i + 1]):
            if full_n[i] or full_n[neighbors[b]]:
                c += 1
        off[a + 1] = off[a] + c
    nbr = np.empty(off[m], dtype=neighbors.dtype)
    bond = np.empty(off[m], dtype=np.int64)
    for a in range(m):
        i = gid_l[a]
        k = off[a]
        for b in range(offsets[i], offsets[i + 1]):
            j = neighbors[b]
            if full_n[i] or full_n[j]:
                nbr[k] = lid_n[j]
                bond[k] = b
                k += 1
    return off, nbr, bond


def build_local(comm, offsets: np.ndarray, neighbors: np.ndarray, part: np.ndarray,
                depth: int) -> Local:
    """This rank's :class:`Local` from the global CSR family and the decomposition
    ``part`` (N,) (collective: the ranks tell each other which rows they need). Memory
    beyond the family: a few bytes per particle and the local rows."""
    if depth < 1:
        raise ValueError(f"halo depth={depth!r}; valid: >= 1")
    n = offsets.shape[0] - 1
    owned_g = part == comm.rank
    full = owned_g.copy()
    for _ in range(depth - 1):
        full |= _partners(offsets, neighbors, full)
    gid = np.flatnonzero(full | _partners(offsets, neighbors, full))
    lid = np.full(n, -1, dtype=np.int64)
    lid[gid] = np.arange(gid.shape[0])
    off, nbr, bond_gid = _local_rows(offsets, neighbors, full, gid, lid)
    send, recv = _exchange_lists(comm, gid, owned_g, part, lid)
    return Local(comm.rank, comm.size, int(depth), n, int(neighbors.shape[0]), gid,
                 owned_g[gid], off, nbr, bond_gid, send, recv, full[gid])


def _exchange_lists(comm, gid, owned_g, part, lid):
    """``(send, recv)``: the halo rows this rank gets from each peer and those it gives
    (collective: the ranks tell each other which rows they need)."""
    halo = gid[~owned_g[gid]]
    need = [halo[part[halo] == p] for p in range(comm.size)]
    asked = comm.alltoall(need)          # the gids each peer needs from me
    recv = [(p, lid[g]) for p, g in enumerate(need) if g.size]
    send = [(p, lid[g]) for p, g in enumerate(asked) if g.size]
    return send, recv


@nb.njit(cache=True)
def _gather_rows(src_off, nbr, order):
    """Rows ``order`` of the CSR ``(src_off, nbr)`` in that order: (offsets, partners)."""
    m = order.shape[0]
    off = np.zeros(m + 1, dtype=np.int64)
    for a in range(m):
        r = order[a]
        off[a + 1] = off[a] + src_off[r + 1] - src_off[r]
    out = np.empty(off[m], dtype=nbr.dtype)
    for a in range(m):
        r = order[a]
        k = off[a]
        for b in range(src_off[r], src_off[r + 1]):
            out[k] = nbr[b]
            k += 1
    return off, out


@nb.njit(cache=True)
def _local_rows_of_complete(off_c, nbr_c, gid_l, full_n, lid_n, goff):
    """Like :func:`_local_rows`, from the complete rows ``(off_c, nbr_c)`` (global
    partners) of the local particles ``gid_l`` and the global row pointers ``goff``."""
    m = gid_l.shape[0]
    off = np.zeros(m + 1, dtype=np.int64)
    for a in range(m):
        i = gid_l[a]
        c = 0
        for b in range(off_c[a], off_c[a + 1]):
            if full_n[i] or full_n[nbr_c[b]]:
                c += 1
        off[a + 1] = off[a] + c
    nbr = np.empty(off[m], dtype=nbr_c.dtype)
    bond = np.empty(off[m], dtype=np.int64)
    for a in range(m):
        i = gid_l[a]
        k = off[a]
        for b in range(off_c[a], off_c[a + 1]):
            j = nbr_c[b]
            if full_n[i] or full_n[j]:
                nbr[k] = lid_n[j]
                bond[k] = goff[i] + (b - off_c[a])
                k += 1
    return off, nbr, bond


def build_local_rows(comm, recipe, part: np.ndarray, depth: int) -> Local:
    """This rank's :class:`Local` built from a
    :class:`~upscale.engine.families.FamilyRecipe` without the whole family (collective).

    The rank builds the complete rows of its owned particles, then of each further
    complete-row layer (the partners of the last), then of the outer halo layer (whose
    complete rows give the global index of its bonds and are dropped after): the same
    rows as the whole family's (:func:`~upscale.engine.families.build_family_rows`), so
    the :class:`Local` equals :func:`build_local`'s on the whole family. Memory: the
    local rows and a few bytes per particle of the body (row lengths, masks)."""
    if depth < 1:
        raise ValueError(f"halo depth={depth!r}; valid: >= 1")
    n = recipe.system.n
    owned_g = part == comm.rank
    full = owned_g.copy()
    ids = [np.flatnonzero(owned_g)]
    cnts, nbrs = [], []
    for layer in range(depth + 1):
        c, j = recipe.rows(ids[-1])
        cnts.append(c)
        nbrs.append(j)
        if layer == depth:
            break
        mark = np.zeros(n, dtype=bool)
        for jj in (nbrs if layer == depth - 1 else nbrs[-1:]):
            mark[jj] = True
        new = np.flatnonzero(mark & ~full)
        del mark
        if layer < depth - 1:
            full[new] = True
        ids.append(new)
    # the global row pointers from the owners' row lengths
    mine = (ids[0], cnts[0])
    counts = np.zeros(n, dtype=np.int64)
    for g, c in comm.allgather(mine):
        counts[g] = c
    goff = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(counts, out=goff[1:])
    del counts
    all_ids = np.concatenate(ids)
    src_off = np.zeros(all_ids.shape[0] + 1, dtype=np.int64)
    np.cumsum(np.concatenate(cnts), out=src_off[1:])
    nbr_all = np.concatenate(nbrs) if len(nbrs) > 1 else nbrs[0]
    del nbrs
    order = np.argsort(all_ids, kind="stable")
    gid = all_ids[order]
    off_c, nbr_c = _gather_rows(src_off, nbr_all, order)
    del nbr_all
    lid = np.full(n, -1, dtype=np.int64)
    lid[gid] = np.arange(gid.shape[0])
    off, nbr, bond_gid = _local_rows_of_complete(off_c, nbr_c, gid, full, lid, goff)
    del off_c, nbr_c
    send, recv = _exchange_lists(comm, gid, owned_g, part, lid)
    return Local(comm.rank, comm.size, int(depth), n, int(goff[-1]), gid, owned_g[gid],
                 off, nbr, bond_gid, send, recv, full[gid])


def bond_states_agree(comm, local: Local, intact: np.ndarray) -> bool:
    """True when every bond held by several ranks has the same state on all of them
    (collective; for tests and checks: it gathers every rank's bond states)."""
    parts = comm.allgather((local.bond_gid, np.asarray(intact, dtype=bool)))
    seen = np.full(local.nb_global, -1, dtype=np.int8)
    for g, v in parts:
        prev = seen[g]
        if np.any((prev >= 0) & (prev != v)):
            return False
        seen[g] = v
    return True
