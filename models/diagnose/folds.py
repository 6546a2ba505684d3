"""Blocked cross-validation folds spread over a recording.

Residuals of a hysteresis model are strongly autocorrelated (a mismatch
lasts as long as the branch or the thermal state that causes it), so rows are
never split one by one: the recording is cut into contiguous blocks of at
least :data:`MIN_BLOCK_S`, and whole blocks are assigned round robin. Every
fourth block forms the final holdout, never used to fit anything; the other
blocks are dealt to ``k`` cross-validation folds, so each fold samples the
whole recording rather than one end of it. Rows within ``guard_s`` of a block
edge are left out of every fit, so that the zero-phase preprocessing filter
cannot leak a held-out measurement into a training row. Rows before
``start_s`` (the initial loading curve, :func:`models.diagnose.design.memory_start_s`)
belong to no fold and no holdout: they are neither fitted nor scored.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Every HOLDOUT_EVERY-th block is final holdout (1/4 = 25 % of the rows).
HOLDOUT_EVERY = 4
#: Cross-validation folds over the training blocks.
CV_FOLDS = 6
#: Blocks per fold and per holdout set (more blocks spread each set wider).
BLOCKS_PER_SET = 4
#: Shortest block (s): longer than the residual correlation of a step response.
MIN_BLOCK_S = 2.0
#: Rows this close (s) to a block edge are not fitted on.
GUARD_S = 0.25
#: Fold of the rows before the start: neither fitted nor scored.
UNSCORED = -2


@dataclass(frozen=True)
class Folds:
    """Block assignment of the rows of one (work-rate) signal.

    Attributes
    ----------
    block : ndarray of int, shape (N,)
        Block index of each row (``-1`` before the start).
    fold : ndarray of int, shape (N,)
        ``-1`` for final holdout rows, :data:`UNSCORED` before the start, else the
        cross-validation fold 0..k-1.
    fit_ok : ndarray of bool, shape (N,)
        False for rows within the guard of a block edge.
    k : int
        Number of cross-validation folds.
    block_edges_s : ndarray, shape (B + 1,)
        Block edges in seconds (to map the assignment to other sample grids).
    block_fold : ndarray of int, shape (B,)
        Fold of each block (``-1`` = holdout).
    start_s : float
        Rows before this time (s) are neither fitted nor scored.
    """

    block: np.ndarray
    fold: np.ndarray
    fit_ok: np.ndarray
    k: int
    block_edges_s: np.ndarray
    block_fold: np.ndarray
    start_s: float = -np.inf

    @property
    def holdout(self) -> np.ndarray:
        """Rows of the final holdout."""
        return self.fold == -1

    @property
    def train(self) -> np.ndarray:
        """Rows a final model may be fitted on (training blocks, guards removed)."""
        return (self.fold >= 0) & self.fit_ok

    def cv_blocks(self) -> list[tuple[slice, int]]:
        """``(rows, fold)`` of every cross-validation block, each a contiguous run of rows (cached)."""
        cached = self.__dict__.get("_blocks")
        if cached is None:
            edges = np.searchsorted(self.block, np.arange(len(self.block_fold) + 1))
            cached = [(slice(int(edges[b]), int(edges[b + 1])), int(self.block_fold[b]))
                      for b in np.flatnonzero((self.block_fold >= 0) & (np.diff(edges) > 0))]
            object.__setattr__(self, "_blocks", cached)
        return cached

    def cv_rows(self) -> np.ndarray:
        """Rows per cross-validation fold, shape (k,) (cached)."""
        cached = self.__dict__.get("_rows")
        if cached is None:
            cached = np.bincount(self.fold[self.fold >= 0], minlength=self.k)
            object.__setattr__(self, "_rows", cached)
        return cached

    def holdout_at(self, t_s: np.ndarray) -> np.ndarray:
        """Holdout flag for samples at times ``t_s`` (any rate) from the block edges."""
        b = np.clip(np.searchsorted(self.block_edges_s, t_s, side="right") - 1, 0, len(self.block_fold) - 1)
        return (self.block_fold[b] < 0) & (t_s >= self.start_s)


def make_folds(
    t_s: np.ndarray,
    k: int = CV_FOLDS,
    holdout_every: int = HOLDOUT_EVERY,
    blocks_per_set: int = BLOCKS_PER_SET,
    min_block_s: float = MIN_BLOCK_S,
    guard_s: float = GUARD_S,
    start_s: float | None = None,
) -> Folds:
    """Cut the time axis into blocks and deal them to holdout and ``k`` folds.

    Parameters
    ----------
    t_s : ndarray
        Sample times (s), increasing.
    k : int
        Cross-validation folds (at least 2).
    holdout_every : int
        Every ``holdout_every``-th block is final holdout.
    blocks_per_set : int
        Wanted number of blocks in each fold; fewer when the recording is short.
    min_block_s, guard_s : float
        Shortest block and edge guard (s).
    start_s : float, optional
        Rows before this time (s) belong to no fold and no holdout; the blocks are laid over the
        whole recording all the same (the first block keeps only its rows from the start on). At
        most the first block is left out, so that every fold keeps all its blocks.

    Raises
    ------
    ValueError
        If the recording is too short for ``k`` folds plus a holdout.
    """
    t_s = np.asarray(t_s, dtype=np.float64)
    duration = t_s[-1] - t_s[0]
    # Training blocks per cycle of `holdout_every` blocks = holdout_every - 1; make the
    # block count a multiple of lcm-ish so each fold gets `blocks_per_set` blocks.
    per_cycle = holdout_every - 1
    cycles = int(np.ceil(k * blocks_per_set / per_cycle))
    n_blocks = cycles * holdout_every
    longest = int(duration // min_block_s)
    if longest < n_blocks:
        cycles = max(longest // holdout_every, int(np.ceil(k / per_cycle)))
        n_blocks = cycles * holdout_every
    if n_blocks * min_block_s > duration * 1.0001 or n_blocks < holdout_every:
        raise ValueError(f"recording of {duration:.1f} s is too short for blocked cross-validation "
                         f"(needs at least {int(np.ceil(k / per_cycle)) * holdout_every * min_block_s:.0f} s)")
    edges = t_s[0] + duration * np.arange(n_blocks + 1) / n_blocks
    edges[-1] = np.nextafter(t_s[-1], np.inf)
    block = np.clip(np.searchsorted(edges, t_s, side="right") - 1, 0, n_blocks - 1)
    block_fold = np.empty(n_blocks, dtype=np.int64)
    j = 0
    for b in range(n_blocks):
        if b % holdout_every == holdout_every - 1:
            block_fold[b] = -1
        else:
            block_fold[b] = j % k
            j += 1
    dist = np.minimum(t_s - edges[block], edges[block + 1] - t_s)
    fit_ok = dist >= guard_s
    fold = block_fold[block]
    start_s = -np.inf if start_s is None else min(float(start_s), float(edges[1]))
    before = t_s < start_s
    block[before], fold[before], fit_ok[before] = -1, UNSCORED, False
    return Folds(block, fold, fit_ok, k, edges, block_fold, start_s)
