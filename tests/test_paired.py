"""How sure a lead is: the paired comparison of two controllers on the same states (`sim.paired`)."""

from __future__ import annotations

import math

import numpy as np
import pytest

import idapbc_pin as ip
from idapbc_pin.evaluation.paired import paired_comparison


def _outcomes(rng, n, p_only_a, p_only_b, p_both):
    """(n,) bool pairs drawn cell by cell from a 2 × 2 table of known probabilities."""
    cell = rng.choice(4, size=n, p=[p_only_a, p_only_b, p_both, 1.0 - p_only_a - p_only_b - p_both])
    return (cell == 0) | (cell == 2), (cell == 1) | (cell == 2)


def test_the_lead_is_the_difference_of_the_success_rates_and_the_cells_add_up():
    rng = np.random.default_rng(0)
    a, b = rng.random(137) < 0.7, rng.random(137) < 0.5
    c = paired_comparison(a, b, "NIDA-PBC", "LQR")
    assert c.only_a + c.only_b + c.both + c.neither == c.n == 137
    assert c.difference == pytest.approx(a.mean() - b.mean(), abs=1e-15)
    lo, hi = c.interval
    assert -1.0 <= lo < c.difference < hi <= 1.0


def test_mcnemar_p_value_is_the_two_sided_binomial_tail_over_the_discordant_states():
    """Checked against the binomial sum written out with math.comb, not against scipy."""
    for only_a, only_b in ((10, 0), (45, 9), (12, 15), (3, 4), (0, 0)):
        a = np.r_[np.ones(only_a), np.zeros(only_b), np.ones(20)].astype(bool)
        b = np.r_[np.zeros(only_a), np.ones(only_b), np.ones(20)].astype(bool)
        k, low = only_a + only_b, min(only_a, only_b)
        tail = sum(math.comb(k, i) for i in range(low + 1)) / 2.0**k if k else 0.5
        assert paired_comparison(a, b).p_value == pytest.approx(min(1.0, 2.0 * tail), rel=1e-12)
    assert paired_comparison(np.ones(10, bool), np.r_[np.zeros(10, bool)]).p_value == pytest.approx(2.0 / 2**10)


def test_swapping_the_controllers_negates_the_lead_and_keeps_the_evidence():
    rng = np.random.default_rng(1)
    a, b = _outcomes(rng, 200, 0.2, 0.1, 0.5)
    ab, ba = paired_comparison(a, b), paired_comparison(b, a)
    assert ba.difference == -ab.difference and ba.p_value == ab.p_value
    assert ba.interval == pytest.approx((-ab.interval[1], -ab.interval[0]), abs=1e-15)


def test_identical_laws_show_no_lead():
    same = np.random.default_rng(2).random(200) < 0.6
    c = paired_comparison(same, same, "NIDA-PBC", "LQR")
    assert c.difference == 0.0 and c.p_value == 1.0
    lo, hi = c.interval
    assert lo == pytest.approx(-hi) and lo < 0.0 < hi


@pytest.mark.parametrize("n, cells", [(200, (0.15, 0.08, 0.55)), (200, (0.02, 0.0, 0.97)), (40, (0.3, 0.1, 0.2)), (100, (0.05, 0.01, 0.9))])
def test_the_95_percent_interval_covers_the_true_lead_about_95_percent_of_the_time(n, cells):
    """Repeated draws of n paired outcomes from a known table: the interval holds the true difference
    p_only_a − p_only_b in 92.5–97.5 % of 2000 draws (Tango's score interval stays near nominal with few
    discordant states too, where a Wald-type interval covered 91 % of draws of the second table)."""
    rng = np.random.default_rng(3)
    truth = cells[0] - cells[1]
    hits = 0
    for _ in range(2000):
        lo, hi = paired_comparison(*_outcomes(rng, n, *cells)).interval
        hits += lo <= truth <= hi
    assert 0.925 <= hits / 2000 <= 0.975


def test_a_clear_lead_is_significant_and_a_coin_flip_is_not():
    rng = np.random.default_rng(4)
    clear = paired_comparison(*_outcomes(rng, 200, 0.2, 0.02, 0.5))
    assert clear.p_value < 1e-4 and clear.interval[0] > 0.0
    flip = paired_comparison(*_outcomes(rng, 200, 0.12, 0.12, 0.5))
    assert flip.p_value > 0.05 or flip.interval[0] < 0.0 < flip.interval[1]


def test_roa_tables_state_the_lead_of_the_first_controller():
    system = ip.load_system("pendubot")
    lqr = ip.LQRController(system)
    res = ip.roa(system, {"LQR": lqr, "none": lambda x: np.zeros((len(x), 1))}, n=6, box="half", T=3.0, dt=0.02)
    c = res.compare("LQR", "none")
    assert c.only_a == int((res["LQR"].success & ~res["none"].success).sum()) and c.n == 6
    assert c.text() in res.table()


def test_settling_is_compared_on_the_states_both_controllers_reach():
    # each controller's own median times it on its own successes, the common one on the same starts
    from idapbc_pin.evaluation.roa import ControllerScore, RoaResult

    def scored(name, t):
        t = np.array(t, float)
        ok = np.isfinite(t)
        return ControllerScore(name, ok, t, np.zeros(5), ok, np.ones(5), ~ok, 0.0)

    box = (-np.ones(2), np.ones(2))
    far = scored("NIDA-PBC", [1.0, 2.0, 3.0, 9.0, 9.0])  # also reaches the two far starts, slowly
    lqr = scored("LQR", [0.5, 1.0, 1.5, np.nan, np.nan])
    res = RoaResult("toy", box, "half", np.zeros((5, 2)), 5.0, 0.01, 0, {"NIDA-PBC": far, "LQR": lqr})
    assert far.median_settling_time == 3.0 and lqr.median_settling_time == 1.0
    assert res.common_settling("NIDA-PBC", "LQR") == {"states": 3, "NIDA-PBC": 2.0, "LQR": 1.0}
    assert "median settle on the 3 states both reach: NIDA-PBC 2.00 s, LQR 1.00 s" in res.table()
    never = scored("none", [np.nan] * 5)
    res = RoaResult("toy", box, "half", np.zeros((5, 2)), 5.0, 0.01, 0, {"NIDA-PBC": far, "none": never})
    assert res.common_settling("NIDA-PBC", "none")["states"] == 0 and "states both reach" not in res.table()


def test_outcomes_of_different_states_are_refused_in_one_line():
    with pytest.raises(ValueError, match="same states"):
        paired_comparison(np.ones(5, bool), np.ones(6, bool), "NIDA-PBC", "LQR")
    with pytest.raises(ValueError, match="level"):
        paired_comparison(np.ones(5, bool), np.ones(5, bool), level=95)
