"""The anchor chooses a form of P that works on ill-conditioned chains, and says which.

Light distal links (the zoo's quad_pendulum) give a Riccati P with a condition number of 1e8–1e11;
at the weights where R = ½P⁻¹Q'P⁻¹ comes out not positive definite in floating point, the anchor
passes that form over for the next of `FALLBACK_FORMS`, stays exact at x*, and the run reports the
choice; so it does where R's condition number is past `MAX_R_COND`. The automatic weight once died on such a candidate weight before training began.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

import idapbc_pin as ip
from idapbc_pin.config import TrainConfig
from idapbc_pin.control import anchor as anchor_module
from idapbc_pin.control.anchor import MAX_P_COND, MAX_R_COND, _anchor_of_form, anchor_settings, formed_anchor, p_condition
from idapbc_pin.errors import IdapbcError
from idapbc_pin.model.zoo import zoo_names


@pytest.fixture(scope="module")
def quad():
    return ip.load_system("quad_pendulum")


def test_the_riccati_form_fails_on_the_four_link_chain_at_a_candidate_weight(quad):
    """The premise: the automatic weight's candidate 0.1 has no Riccati anchor with R ≻ 0."""
    with pytest.raises(ValueError, match="not positive definite"):
        _anchor_of_form(quad, TrainConfig.fast(), "box", 0.1, "riccati")


def test_the_automatic_weight_no_longer_dies_on_the_four_link_chain(quad):
    """`anchor_settings` tried the candidate 0.1 and raised; now a candidate gets an anchor in some form."""
    scaling, anchor_q = anchor_settings(quad, TrainConfig.fast())
    assert scaling == "box" and anchor_q in (10.0, 1.0, 0.1, 0.01)
    assert formed_anchor(quad, TrainConfig.fast(), (scaling, anchor_q))[0] is not None


@pytest.mark.parametrize("anchor_q", [0.0, 0.1])
def test_the_four_link_chain_gets_an_exact_anchor(quad, anchor_q):
    """Automatic weight, and the weight 0.1 whose Riccati form fails: an exact pH form of the LQR loop,
    in the Riccati form where it works and in another (named, with why) where it does not."""
    config = TrainConfig.fast(anchor_q=anchor_q)
    settings = anchor_settings(quad, config)
    anchor, form, why = formed_anchor(quad, config, settings)
    if anchor_q == 0.1:
        assert form != "riccati" and "'riccati' gave no positive-definite R" in why
    else:  # the Riccati R spans ~1e15 in the networks' units, past what float64 keeps positive definite
        assert form != "riccati" and why.startswith("'riccati' gave cond(R) = ")
    assert p_condition(quad, anchor.P, settings[0]) <= MAX_P_COND
    assert p_condition(quad, anchor.R, settings[0], inverse=True) <= MAX_R_COND
    A, B = quad.linearization()
    np.testing.assert_allclose(anchor.A_cl, A - B @ anchor.K, rtol=0, atol=1e-14 * np.abs(anchor.A_cl).max())
    assert np.linalg.eigvals(anchor.A_cl).real.max() < 0
    np.linalg.cholesky(anchor.P)
    np.linalg.cholesky(anchor.R)
    np.testing.assert_array_equal(anchor.J + anchor.J.T, 0.0)
    err = np.abs((anchor.J - anchor.R) @ anchor.P - anchor.A_cl).max()
    assert err <= 1e-8 * np.abs(anchor.A_cl).max()
    g_perp = quad.g_perp(quad.x_star)
    np.testing.assert_allclose(g_perp @ (anchor.A_cl - A), 0.0, atol=1e-10 * np.abs(anchor.K).max())


@pytest.mark.parametrize("anchor_q", [0.0, 0.1])
def test_networks_on_the_four_link_chain_close_the_lqr_loop_at_the_target(quad, anchor_q):
    """float64 networks anchored in the chosen form: the closed loop's Jacobian at x* is A − BK, and
    the resolved config (config.json) records the form."""
    from idapbc_pin.control.controller import Controller
    from idapbc_pin.control.nets import build_nets
    from idapbc_pin.training.train import resolved_config

    config = resolved_config(quad, TrainConfig.fast(dtype="float64", anchor_q=anchor_q))
    assert config.anchor_p == formed_anchor(quad, TrainConfig.fast(anchor_q=anchor_q))[1]
    torch.manual_seed(0)
    ctrl = Controller(quad, build_nets(quad, config))
    A_cl = formed_anchor(quad, config)[0].A_cl
    np.testing.assert_allclose(ctrl.closed_loop_jacobian(), A_cl, rtol=0, atol=1e-6 * np.abs(A_cl).max())


@pytest.mark.parametrize("name", zoo_names())
def test_the_zoo_robots_keep_the_configured_form(name):
    """Every zoo robot keeps the configured form, but where its R spans more than `MAX_R_COND`: the
    four-link chain's Riccati form (above) and the reaction wheel's box form (2.5e14)."""
    passed_over = {("quad_pendulum", "riccati"): "box", ("reaction_wheel", "box"): "riccati"}
    system = ip.load_system(name)
    for config in (TrainConfig.fast(), TrainConfig.fast(anchor_p="box")):
        _, form, why = formed_anchor(system, config)
        if (name, config.anchor_p) in passed_over:
            assert form == passed_over[name, config.anchor_p] and why.startswith(f"'{config.anchor_p}' gave cond(R) = ")
        else:
            assert (form, why) == (config.anchor_p, "")


def test_the_train_summary_says_which_form_was_chosen():
    from types import SimpleNamespace

    from idapbc_pin.training.summary import format_train_summary

    summary = {"status": "finished", "epochs_done": 1, "train_seconds": 1.0, "final_terms": {"matching": 0.1},
               "eigenvalues_at_target": [[-2.0, 0.0]], "locally_exponentially_stable": True,
               "anchor_form": {"form": "box", "passed_over": "'riccati' gave cond(P) = 1.2e+09"}}
    text = format_train_summary(SimpleNamespace(path="RUN", summary=summary, config=TrainConfig(scaling="box", anchor_q=1.0, anchor_p="box")))
    assert "anchor: P of form 'box', chosen over the configured one ('riccati' gave cond(P) = 1.2e+09)" in text


def test_no_form_that_works_is_one_line_with_a_fix(quad, monkeypatch):
    def failing(*args, **kwargs):
        raise ValueError("R = ½P⁻¹Q'P⁻¹ is numerically not positive definite; try P_mode='riccati'")

    monkeypatch.setattr(anchor_module, "lqr_anchor", failing)
    with pytest.raises(IdapbcError) as excinfo:
        formed_anchor(quad, TrainConfig.fast(), ("box", 1.0))
    message = str(excinfo.value)
    assert "\n" not in message and "Fix:" in message
    assert all(f"'{form}'" in message for form in ("riccati", "box", "lyapunov"))


def test_float32_networks_are_checked_in_float64(quad):
    """Condition (i) is a property of the weights: a float32 network of the four-link chain rounds its
    R_d into an indefinite matrix (the premise), and the structural check, in float64, does not."""
    from idapbc_pin.certificate.checks import check_structural
    from idapbc_pin.certificate.terms import closed_loop_terms
    from idapbc_pin.control.controller import Controller
    from idapbc_pin.control.nets import build_nets
    from idapbc_pin.sim.states import uniform_states
    from idapbc_pin.training.train import resolved_config

    torch.manual_seed(0)
    ctrl = Controller(quad, build_nets(quad, resolved_config(quad, TrainConfig.fast())))
    exact = ctrl.in_float64()
    assert exact.nets.x_star.dtype == torch.float64 and exact.in_float64() is exact
    x = uniform_states(quad, 64, "domain", 0)
    assert np.linalg.eigvalsh(ctrl.R_d(x))[:, 0].min() < 0
    np.testing.assert_allclose(exact(x), ctrl(x), rtol=1e-3, atol=1e-3 * np.abs(ctrl(x)).max())
    structural = check_structural(ctrl, quad, closed_loop_terms(ctrl, x, quad), n_hessian=8)
    assert structural.min_eig_R > 0
