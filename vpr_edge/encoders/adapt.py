"""A map fitted to its route: a linear map of the encodings learned from labelled drives (``vpr-edge adapt``).

Each labelled frame is paired with its place's reference. Three steps, each learned on the pairs:

1. **Gains** (``adapt_gains``, IFV and VLAD maps): one gain a codebook entry, learned so that each frame's
   cosines favour its own place's reference over the others' (the entries that describe snow or light weigh
   less);
2. **Within-place whitening**: the differences within the pairs span what the drive's conditions change and
   not the place; their ``rank`` strongest directions are whitened, shrunk towards the rest (``shrink``);
3. **Gains** again, learned on the pairs as steps 1-2 map them.

    y = unit(g_out * W(g_in * x)),   W(v) = v - B^T ((1 - keep) * (B v)),
    keep_i = sqrt(l / (e_i + l)),   l = shrink * mean(e_1 .. e_rank)

with ``B`` (rank, D) the differences' principal directions and ``e`` their variances; ``g_in``, ``g_out``
(D,) are 1 without gains. The map is D -> D (identity outside ``B``), so the stored rows keep their size and
storage. A full linear map (LDA, a ridge map of frames onto references, a whitening of the whole space) lost
on nordland-dev: 400 places are too few to estimate it.

What suits one front end does not suit another (80 directions help a 1,968-dim IFV and hurt a 112-dim GeM
descriptor; gains help the 41-component IFV and hurt a 128-component one), so the recipe is chosen on the
drive itself (``choose_recipe``): the pairs are split at their median place, each recipe (``RANKS``, with
and without gains on a codebook map, ``Encoder.groups``) is learned on one half and scored on the other and
the reverse, and the best, refitted on every pair, is kept (docs/decisions.md, "`adapt`: chosen on the
drive's own places").

References are mapped once, when the map is adapted; each query encoding is mapped in ``PlaceMap.encode``,
so ``localize``, ``evaluate`` and the index all see mapped encodings.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vpr_edge.encoders.base import unit_rows

RANKS = (20, 80)    # directions of within-place change whitened: the choices tried on the drive's held-out places
SHRINK = 0.1        # their variances shrunk towards this share of their mean (0: whitened fully)
MIN_PAIRS = 50      # labelled frames a drive (or drives) must give to learn from
PAIRS_PER_RANK = 4  # at least this many pairs a direction: fewer pairs learn fewer directions


@dataclass(frozen=True)
class Adaptation:
    """The learned map (module docstring): ``basis`` (m, D) float32 orthonormal rows, ``keep`` (m,) float32 in
    (0, 1], what each direction keeps of its length; ``gain_in``, ``gain_out`` (D,) float32 > 0, the gains
    before and after (None: 1 everywhere, as in a map adapted without them)."""

    basis: np.ndarray
    keep: np.ndarray
    gain_in: np.ndarray | None = None
    gain_out: np.ndarray | None = None

    @property
    def dim(self) -> int:
        return int(self.basis.shape[1])

    def apply(self, x: np.ndarray) -> np.ndarray:
        """Encodings (B, D) of any positive scale -> mapped unit encodings (B, D) float32 (a zero row stays
        zero)."""
        x = np.atleast_2d(np.asarray(x, np.float32))
        if self.gain_in is not None:
            x = x * self.gain_in
        y = x - ((x @ self.basis.T) * (1.0 - self.keep)) @ self.basis
        if self.gain_out is not None:
            y *= self.gain_out
        norm = np.linalg.norm(y, axis=1, keepdims=True)
        return np.divide(y, norm, out=np.zeros_like(y), where=norm > 0).astype(np.float32)

    def to_arrays(self) -> dict[str, np.ndarray]:
        out = {"adapt_basis": self.basis.astype(np.float32), "adapt_keep": self.keep.astype(np.float32)}
        for name in ("gain_in", "gain_out"):
            if getattr(self, name) is not None:
                out["adapt_" + name] = getattr(self, name).astype(np.float32)
        return out

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], dim: int) -> "Adaptation":
        """From a map's ``adapt_basis``, ``adapt_keep`` and, where held, ``adapt_gain_in`` / ``adapt_gain_out``;
        ValueError unless they fit ``dim`` dims, are finite, the rows orthonormal, ``keep`` in (0, 1] and the
        gains positive."""
        basis = np.array(arrays["adapt_basis"], np.float32)   # into RAM (a memory-mapped map)
        keep = np.array(arrays["adapt_keep"], np.float32)
        if basis.ndim != 2 or basis.shape[1] != dim or keep.shape != (basis.shape[0],) or not len(keep):
            raise ValueError(f"adaptation {basis.shape} and {keep.shape} do not fit {dim}-dim encodings")
        if not (np.isfinite(basis).all() and np.isfinite(keep).all()) or (keep <= 0).any() or (keep > 1).any():
            raise ValueError("adaptation holds non-finite values, or keeps outside (0, 1]")
        if np.abs(basis @ basis.T - np.eye(len(keep), dtype=np.float32)).max() > 1e-3:
            raise ValueError("adaptation's directions are not orthonormal")
        gains = []
        for name in ("adapt_gain_in", "adapt_gain_out"):
            g = None if name not in arrays else np.array(arrays[name], np.float32)
            if g is not None and (g.shape != (dim,) or not np.isfinite(g).all() or (g <= 0).any()):
                raise ValueError(f"adaptation's {name[6:]} is not {dim} positive finite gains")
            gains.append(g)
        return cls(basis, keep, *gains)


def middle_refs(truth: np.ndarray) -> np.ndarray:
    """Padded ground truth (Q, T) (-1: none) -> each frame's one reference to pair with (Q,) int64: the middle
    of its sorted true references (-1: a frame of no place)."""
    t = np.sort(np.where(np.asarray(truth) < 0, np.iinfo(np.int64).max, truth).astype(np.int64), axis=1)
    count = (np.asarray(truth) >= 0).sum(axis=1)
    mid = t[np.arange(len(t)), np.maximum(count - 1, 0) // 2]
    return np.where(count > 0, mid, -1)


def rank_for(pairs: int, rank: int = max(RANKS)) -> int:
    """The directions learned from ``pairs`` labelled frames: ``rank``, fewer where pairs are few."""
    return max(1, min(rank, pairs // PAIRS_PER_RANK))


def fit_within_place(queries: np.ndarray, refs: np.ndarray, rank: int = max(RANKS), shrink: float = SHRINK
                     ) -> Adaptation:
    """Labelled frames' encodings ``queries`` (N, D) and their places' references ``refs`` (N, D), row by row
    (any positive scale: each row is made unit) -> the within-place whitening (module docstring, step 2) of
    the ``rank_for(N, rank)`` strongest directions. ValueError for no pairs or ``shrink`` <= 0."""
    q, r = unit_rows(queries), unit_rows(refs)
    if q.shape != r.shape or not len(q):
        raise ValueError(f"need matching pairs, got {q.shape} and {r.shape}")
    if shrink <= 0:
        raise ValueError(f"shrink must be > 0, got {shrink}")
    diff = q - r
    _, s, vt = np.linalg.svd(diff, full_matrices=False)
    var = s ** 2 / len(diff)
    m = min(rank_for(len(diff), rank), int((var > 0).sum()) or 1)
    floor = shrink * float(var[:m].mean()) if var[:m].any() else 1.0
    keep = np.sqrt(floor / (var[:m] + floor))
    return Adaptation(vt[:m].astype(np.float32), keep.astype(np.float32))


@dataclass(frozen=True)
class Recipe:
    """What ``adapt`` learns: ``rank`` directions whitened, with gains before and after (``gains``) or not."""

    rank: int
    gains: bool

    @property
    def name(self) -> str:
        return f"rank {self.rank}" + (" with gains" if self.gains else "")


@dataclass(frozen=True)
class Choice:
    """The recipe kept and every recipe's held-out R@1 (``choose_recipe``; "unadapted": the map as it is)."""

    recipe: Recipe
    scores: dict[str, float]


def fit_recipe(queries: np.ndarray, refs: np.ndarray, places: np.ndarray, groups: np.ndarray | None,
               recipe: Recipe, shrink: float = SHRINK, gain_in: np.ndarray | None = None) -> Adaptation:
    """``recipe`` (module docstring, steps 1-3; step 2 alone without gains) learned from labelled pairs:
    frames' encodings ``queries`` and their places' references ``refs`` (N, D), each pair's place ``places``
    (N,), the encoder's ``groups`` (D,) (None: no gains); ``gain_in``: step 1's gains on these pairs, if
    fitted already (``first_gains``; they do not depend on the rank)."""
    if not recipe.gains or groups is None:
        return fit_within_place(queries, refs, recipe.rank, shrink)
    from vpr_edge.encoders.adapt_gains import fit_gains

    q, r = unit_rows(queries).astype(np.float64), unit_rows(refs).astype(np.float64)
    if q.shape != r.shape or len(groups) != q.shape[1] or len(places) != len(q):
        raise ValueError(f"need matching pairs, places and groups, got {q.shape}, {r.shape}, {len(places)} and "
                         f"{len(groups)}")
    g_in = fit_gains(q, r, places, groups) if gain_in is None else gain_in
    white = fit_within_place(q * g_in, r * g_in, recipe.rank, shrink)
    first = Adaptation(white.basis, white.keep, g_in.astype(np.float32))
    g_out = fit_gains(first.apply(q), first.apply(r), places, groups)
    return Adaptation(white.basis, white.keep, first.gain_in, g_out.astype(np.float32))


def first_gains(queries: np.ndarray, refs: np.ndarray, places: np.ndarray, groups: np.ndarray | None
                ) -> np.ndarray | None:
    """Step 1's gains on labelled pairs (``fit_recipe``'s arguments; None without ``groups``)."""
    if groups is None:
        return None
    from vpr_edge.encoders.adapt_gains import fit_gains

    return fit_gains(unit_rows(queries).astype(np.float64), unit_rows(refs).astype(np.float64), places, groups)


def held_out_r1(adaptation: Adaptation | None, queries: np.ndarray, refs: np.ndarray, places: np.ndarray) -> float:
    """The share of frames ``queries`` (N, D) whose most similar of the references ``refs`` (N, D) lies within
    ``adapt_gains.TOLERANCE`` places of their own (``places`` (N,)), each set mapped by ``adaptation`` (None:
    as it is) and centred on its own mean: one frame's R@1 on standardised cosines."""
    from vpr_edge.encoders.adapt_gains import TOLERANCE

    q, r = (unit_rows(queries), unit_rows(refs)) if adaptation is None else (adaptation.apply(queries),
                                                                              adaptation.apply(refs))
    q, r = unit_rows(q - q.mean(axis=0)), unit_rows(r - r.mean(axis=0))
    best = np.argmax(q @ r.T, axis=1)
    return float(np.mean(np.abs(places[best] - places) <= TOLERANCE))


def choose_recipe(queries: np.ndarray, refs: np.ndarray, places: np.ndarray, groups: np.ndarray | None,
                  ranks: tuple[int, ...] = RANKS, shrink: float = SHRINK) -> Choice:
    """The recipe of ``ranks`` x (gains or not, on a codebook map) with the best held-out R@1 (module
    docstring): learned on the pairs below the median place, scored on the rest, and the reverse, averaged.
    With under ``MIN_PAIRS // 2`` pairs a side, the largest rank (with gains on a codebook map), unscored."""
    places = np.asarray(places, np.int64)
    low = places < np.median(places)
    if min(int(low.sum()), int((~low).sum())) < MIN_PAIRS // 2:
        return Choice(Recipe(max(ranks), groups is not None), {})
    sides = [(low, ~low), (~low, low)]
    q, r = np.asarray(queries), np.asarray(refs)
    scores = {"unadapted": float(np.mean([held_out_r1(None, q[b], r[b], places[b]) for _, b in sides]))}
    gains = [first_gains(q[a], r[a], places[a], groups) for a, _ in sides]   # each side's step 1, once
    best: Recipe | None = None
    for recipe in [Recipe(k, g) for k in ranks for g in ((False, True) if groups is not None else (False,))]:
        scores[recipe.name] = float(np.mean([
            held_out_r1(fit_recipe(q[a], r[a], places[a], groups, recipe, shrink, g_in), q[b], r[b], places[b])
            for (a, b), g_in in zip(sides, gains)]))
        if best is None or scores[recipe.name] > scores[best.name]:
            best = recipe
    assert best is not None
    return Choice(best, scores)


def fit_adaptation(queries: np.ndarray, refs: np.ndarray, places: np.ndarray, groups: np.ndarray | None = None,
                   rank: int | None = None, shrink: float = SHRINK) -> tuple[Adaptation, Choice]:
    """The adaptation of labelled pairs (``fit_recipe``'s arguments), its recipe chosen on the pairs' own
    held-out places (``choose_recipe``; ``rank`` given: that rank alone) and refitted on every pair."""
    choice = choose_recipe(queries, refs, places, groups, RANKS if rank is None else (rank,), shrink)
    return fit_recipe(queries, refs, places, groups, choice.recipe, shrink), choice
