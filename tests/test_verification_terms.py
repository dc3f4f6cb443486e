"""The opt-in terms aimed at the certified set: what they penalise is what the certificate checks,
they are off by default, and a run that trains them resumes exactly."""

from __future__ import annotations

import csv

import numpy as np
import pytest
import torch

import idapbc_pin as ip
from idapbc_pin.control.nets import build_nets
from idapbc_pin.model.boxes import verification_box
from idapbc_pin.training.verification import RATE, box_faces, verification_terms


def test_kept_counter_examples_are_states_of_the_set_where_h_d_does_not_decay_along_the_saturated_loop():
    torch.manual_seed(0)
    system = ip.load_system("pendubot")
    nets = build_nets(system, ip.TrainConfig(width=16, depth=2, seed=0))
    lo, hi = verification_box(system)
    gen = torch.Generator().manual_seed(0)
    x_v = lo + (hi - lo) * torch.rand(400, system.n, generator=gen, dtype=torch.float64).numpy()
    x_face = box_faces(lo, hi, 256, gen)
    effort = torch.tensor(np.array(system.effort), dtype=torch.float64)
    x_train = torch.as_tensor(system.domain[0] + (system.domain[1] - system.domain[0]) * np.random.default_rng(1).random((64, 4)))
    terms, kept = verification_terms(nets, nets.H(x_train), torch.as_tensor(x_v), torch.as_tensor(system.f(x_v)), torch.as_tensor(x_face), effort)
    assert terms["set_decrease"].requires_grad and terms["set_coverage"].requires_grad
    assert kept.shape[0] > 0 and float(terms["set_decrease"].detach()) > 0
    # independently: the level, the applied input and Ḣ_d by central differences of H_d along ẋ
    x = kept.numpy()
    with torch.no_grad():
        c_v = float(nets.H(torch.as_tensor(x_face)).min())
        H = nets.H(kept).numpy()
        _, _, _, _, f_d = nets.desired(kept.clone().requires_grad_(True))
    u = np.clip(((f_d.detach() - torch.as_tensor(system.f(x))) @ nets.g_pinv.T).numpy(), -system.effort, system.effort)
    x_dot = system.f(x) + np.einsum("nim,nm->ni", system.g(x), u)
    h = 1e-6
    with torch.no_grad():
        H_dot = (nets.H(torch.as_tensor(x + h * x_dot)) - nets.H(torch.as_tensor(x - h * x_dot))).numpy() / (2 * h)
    assert np.all(H < c_v) and np.all(H_dot / H + RATE > -1e-6)
    # the coverage term: the mean e-folds by which the training samples lie above the level
    with torch.no_grad():
        expected = np.maximum(np.log(nets.H(x_train).numpy() / c_v), 0).mean()
    assert float(terms["set_coverage"].detach()) == pytest.approx(expected, rel=1e-9)


def _terms(run) -> dict[str, float]:
    rows = list(csv.DictReader(open(run.path / "metrics.csv")))
    return {k: max(float(r[k]) for r in rows) for k in ("set_decrease", "set_coverage")}


def test_the_terms_are_off_by_default_and_a_run_that_trains_them_resumes_exactly(tmp_path):
    torch.set_num_threads(1)
    system = ip.load_system("pendubot")
    small = dict(epochs=6, width=8, depth=1, samples=32, face_samples=16, fallback="none", checkpoint_every=3)
    plain = ip.train(system, ip.TrainConfig(**small), out=tmp_path / "plain", progress=False)
    assert _terms(plain) == {"set_decrease": 0.0, "set_coverage": 0.0}
    config = ip.TrainConfig(**small, verification_terms=True)
    whole = ip.train(system, config, out=tmp_path / "whole", progress=False)
    assert _terms(whole)["set_coverage"] > 0
    half = ip.train(system, config.replace(epochs=3), out=tmp_path / "half", progress=False)
    resumed = ip.train(system, config, out=tmp_path / "half", resume=half.path, progress=False)
    for a, b in zip(whole.controller.nets.parameters(), resumed.controller.nets.parameters()):
        assert torch.equal(a, b)
