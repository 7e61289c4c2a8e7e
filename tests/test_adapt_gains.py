"""``adapt``'s codebook gains (``encoders.adapt_gains``): the loss against plain loops, its gradient against finite
differences, planted seasons weighed down, the encoders' groups where their gradients lie, and an adaptation
with gains stored and checked."""
from __future__ import annotations

import numpy as np
import pytest

from vpr_edge.encoders.adapt import Adaptation, Recipe, choose_recipe, fit_adaptation, fit_recipe, held_out_r1
from vpr_edge.encoders.adapt_gains import GroupSums, contrastive_loss, fit_gains
from vpr_edge.encoders.fisher import FisherVector, Gmm, fisher_gradients
from vpr_edge.encoders.words import Vlad

pytest.importorskip("scipy")

GROUPS, WIDTH = 6, 5          # codebook entries, dimensions each
PLACE_GROUPS = 3              # entries 0-2 see the place; 3-5 the season (queries only)


def _unit(x: np.ndarray) -> np.ndarray:
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def planted(places: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(queries, references, groups): each place a random pattern in the place entries, seen by both drives
    with a little noise; every query frame also carries a strong season of its own in the other entries."""
    rng = np.random.default_rng(seed)
    dim = GROUPS * WIDTH
    groups = np.repeat(np.arange(GROUPS), WIDTH)
    place = np.where(groups < PLACE_GROUPS, 1.0, 0.0) * rng.normal(size=(places, dim))
    season = np.where(groups >= PLACE_GROUPS, 1.0, 0.0)
    refs = place + 0.3 * rng.normal(size=place.shape) + 0.3 * season * rng.normal(size=place.shape)
    queries = place + 0.3 * rng.normal(size=place.shape) + 2.0 * season * rng.normal(size=place.shape)
    return queries, refs, groups


def plain_loss(theta, q, r, groups, near, tau, reg) -> float:
    """The loss written as loops over pairs."""
    w = np.exp(theta)[groups]
    n = len(q)
    s = np.array([[np.sum(w * q[i] * r[j]) / np.sqrt(np.sum(w * q[i] ** 2) * np.sum(w * r[j] ** 2))
                   for j in range(n)] for i in range(n)])
    loss = 0.0
    for m in (s, s.T):
        for i in range(n):
            e = np.exp(m[i] / tau)
            loss -= np.log(sum(e[j] for j in range(n) if near[i, j]) / e.sum()) / n
    return loss + reg * float(theta @ theta) / len(theta)


def test_the_loss_is_a_plain_loop_and_its_gradient_exact() -> None:
    rng = np.random.default_rng(1)
    q, r = rng.normal(size=(12, GROUPS * WIDTH)), rng.normal(size=(12, GROUPS * WIDTH))
    groups = np.repeat(np.arange(GROUPS), WIDTH)
    places = np.array([0, 1, 2, 5, 6, 9, 12, 13, 20, 21, 22, 30])
    near = np.abs(places[:, None] - places[None, :]) <= 2
    theta = 0.3 * rng.normal(size=GROUPS)
    sums = GroupSums.of(q, r, groups)
    loss, grad = contrastive_loss(theta, sums, near, tau=0.1, reg=0.5)
    assert loss == pytest.approx(plain_loss(theta, q, r, groups, near, 0.1, 0.5), rel=1e-6)   # float32 sums
    step = 1e-6
    numeric = [(contrastive_loss(theta + step * e, sums, near, 0.1, 0.5)[0]
                - contrastive_loss(theta - step * e, sums, near, 0.1, 0.5)[0]) / (2 * step)
               for e in np.eye(GROUPS)]
    np.testing.assert_allclose(grad, numeric, rtol=1e-5, atol=1e-8)


def test_the_entries_that_see_the_season_are_weighed_down() -> None:
    queries, refs, groups = planted(120)
    gains = fit_gains(queries, refs, np.arange(120), groups, tau=0.1)
    per_group = gains[::WIDTH]
    assert per_group[:PLACE_GROUPS].min() > 1.0 > per_group[PLACE_GROUPS:].max(), per_group


def test_gains_help_on_places_not_learned_from() -> None:
    queries, refs, groups = planted(240, seed=2)
    half = 120

    def r1(ad: Adaptation | None) -> float:
        q, r = queries[half:], refs[half:]
        if ad is not None:
            q, r = ad.apply(q), ad.apply(r)
        return float(np.mean(np.argmax(_unit(q) @ _unit(r).T, axis=1) == np.arange(len(q))))

    with_gains = fit_recipe(queries[:half], refs[:half], np.arange(half), groups, Recipe(4, True))
    without = fit_recipe(queries[:half], refs[:half], np.arange(half), groups, Recipe(4, False))
    assert with_gains.gain_in is not None and with_gains.gain_out is not None
    assert r1(with_gains) > r1(without) + 0.05 and r1(with_gains) > r1(None) + 0.2, (r1(None), r1(without),
                                                                                      r1(with_gains))


def test_an_adaptation_with_gains_is_stored_and_checked() -> None:
    queries, refs, groups = planted(80)
    ad = fit_recipe(queries, refs, np.arange(80), groups, Recipe(4, True))
    dim = GROUPS * WIDTH
    again = Adaptation.from_arrays(ad.to_arrays(), dim)
    x = np.random.default_rng(3).normal(size=(4, dim))
    np.testing.assert_array_equal(again.apply(x), ad.apply(x))
    for name, bad in (("adapt_gain_in", -ad.gain_in), ("adapt_gain_out", ad.gain_out[:-1]),
                      ("adapt_gain_in", ad.gain_in * np.nan)):
        with pytest.raises(ValueError, match="positive finite gains"):
            Adaptation.from_arrays(ad.to_arrays() | {name: bad}, dim)
    old = {k: v for k, v in ad.to_arrays().items() if "gain" not in k}   # a map adapted without gains
    assert Adaptation.from_arrays(old, dim).gain_in is None


def test_each_encoders_groups_are_where_its_entries_lie() -> None:
    """A descriptor at one GMM component's mean moves only that component's dimensions; VLAD's blocks are
    its centres, row by row."""
    rng = np.random.default_rng(4)
    means = 10.0 * rng.normal(size=(3, 4))
    gmm = Gmm(np.full(3, 1 / 3), means, np.full((3, 4), 0.01))
    fv = FisherVector(gmm, None, 4)
    y = (means[1] + 0.05 * rng.normal(size=(6, 4)))[None]
    g = fisher_gradients(y, np.ones((1, 6)), gmm)[0]
    groups = fv.groups()
    assert groups.shape == (fv.dim,) and set(np.flatnonzero(np.abs(g) > 1e-6 * np.abs(g).max())) <= set(
        np.flatnonzero(groups == 1))
    vlad = Vlad(rng.normal(size=(5, 3)), None, 3)
    assert vlad.groups().tolist() == [c for c in range(5) for _ in range(3)]


def test_the_recipe_is_chosen_on_the_pairs_own_held_out_places() -> None:
    """Each recipe learned below the median place and scored above it, and the reverse; the best is refitted."""
    queries, refs, groups = planted(160, seed=5)
    places = np.arange(160)
    choice = choose_recipe(queries, refs, places, groups, ranks=(2, 4))
    assert set(choice.scores) == {"unadapted", "rank 2", "rank 2 with gains", "rank 4", "rank 4 with gains"}
    low = places < 80
    for recipe in (Recipe(2, False), Recipe(4, True)):   # each score as the docstring says, by hand
        by_hand = np.mean([held_out_r1(fit_recipe(queries[a], refs[a], places[a], groups, recipe), queries[b],
                                       refs[b], places[b]) for a, b in ((low, ~low), (~low, low))])
        assert choice.scores[recipe.name] == pytest.approx(by_hand)
    assert choice.recipe.gains and choice.scores[choice.recipe.name] == max(choice.scores.values())
    ad, again = fit_adaptation(queries, refs, places, groups)
    assert again == choose_recipe(queries, refs, places, groups) and ad.gain_in is not None
    one, only = fit_adaptation(queries, refs, places, None, rank=3)   # no codebook: no gains; one rank given
    assert set(only.scores) == {"unadapted", "rank 3"} and one.gain_in is None and len(one.keep) == 3


def test_held_out_r1_is_a_plain_loop() -> None:
    queries, refs, _ = planted(40, seed=6)
    places = np.arange(40) * 3

    def centred(x):
        x = x / np.linalg.norm(x, axis=1, keepdims=True)
        return x - x.mean(axis=0)

    q, r = centred(queries), centred(refs)
    right = 0
    for i in range(40):
        cos = [q[i] @ r[j] / np.linalg.norm(q[i]) / np.linalg.norm(r[j]) for j in range(40)]
        right += abs(places[int(np.argmax(cos))] - places[i]) <= 2
    assert held_out_r1(None, queries, refs, places) == pytest.approx(right / 40)
