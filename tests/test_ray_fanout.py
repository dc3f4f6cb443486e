"""The recovery stage's fan-out over Ray (`idapbc_pin._parallel.process_map(..., ray=...)`).

Claims:
* over Ray tasks, `process_map` yields exactly what a loop gives, in the jobs' order, one thread each;
* `compare_laws` (every gate's judge) gives the same verdicts on Ray as in this process;
* `RecoveryConfig.ray` is read from a config file as an address;
* `recover --ray` and `train --recover auto --ray` where Ray is not installed: exit status 2, one
  line naming the fix, before anything runs.
Ray is an optional extra (pip install 'idapbc-pin[ray]'): the tests that run it skip without it.
"""

from __future__ import annotations

import os
import sys

import numpy as np
import pytest

import idapbc_pin as ip
from idapbc_pin._parallel import init_ray, process_map
from idapbc_pin.cli.main import main
from idapbc_pin.control.baseline import LQRController
from idapbc_pin.errors import IdapbcError
from idapbc_pin.recovery.config import RecoveryConfig
from idapbc_pin.sim.compare import compare_laws
from idapbc_pin.sim.states import scaled_box, uniform_states

INSTALL_HINT = "pip install 'idapbc-pin[ray]'"


@pytest.fixture(scope="module")
def local_ray():
    """A local Ray instance of 2 CPUs, started through `init_ray` as `--ray auto` starts it; this
    module's functions travel to its workers by value (the workers cannot import tests/)."""
    ray = pytest.importorskip("ray", reason=f"Ray is an optional extra ({INSTALL_HINT}): not installed here")
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
    with pytest.MonkeyPatch.context() as patch:
        patch.delenv("RAY_ADDRESS", raising=False)
        init_ray(ray, "auto", 2)
    yield ray
    ray.shutdown()
    ray.cloudpickle.unregister_pickle_by_value(sys.modules[__name__])


def _square_threads_pid(k: int) -> tuple[int, list[int], int]:
    import torch
    from threadpoolctl import threadpool_info

    return k * k, [torch.get_num_threads()] + [pool["num_threads"] for pool in threadpool_info()], os.getpid()


def test_process_map_over_ray_gives_what_a_loop_gives_in_order_one_thread_each(local_ray):
    jobs = list(range(7))
    loop = [v for v, _, _ in map(_square_threads_pid, jobs)]
    on_ray = list(process_map(_square_threads_pid, jobs, 0, ray="auto"))
    assert [v for v, _, _ in on_ray] == loop == [k * k for k in jobs]
    assert {pid for _, _, pid in on_ray} != {os.getpid()}  # they ran as Ray tasks
    assert all(set(threads) == {1} for _, threads, _ in on_ray)
    assert [v for v, _, _ in process_map(_square_threads_pid, jobs, 1, ray="auto")] == loop  # one task at a time


def test_compare_laws_gives_the_same_verdicts_on_ray_as_in_this_process(local_ray):
    system = ip.load_system("pendubot", effort={"shoulder": 8.0})
    lqr = LQRController(system)
    x0 = np.concatenate([uniform_states(system, 2, scaled_box(system, 0.05), seed=3), uniform_states(system, 2, "domain", seed=3)])
    runs = [(lqr, x0), (lqr, x0[::-1].copy())]  # near x* first, then from the training box; then reversed
    here = list(compare_laws(system, runs, T=4.0, dt=0.01, workers=1))
    on_ray = list(compare_laws(system, runs, T=4.0, dt=0.01, workers=0, ray="auto"))
    assert len(here) == len(on_ray) == 2
    for (ok, left), (ok_ray, left_ray) in zip(here, on_ray):
        np.testing.assert_array_equal(ok, ok_ray)
        assert left is None and left_ray is None
    assert here[0][0][:2].all() and np.array_equal(here[0][0], here[1][0][::-1])  # near x*: brought there; the order kept


def test_the_recovery_config_reads_ray_from_a_file(tmp_path):
    path = tmp_path / "recovery.toml"
    path.write_text('[recovery]\nray = "ray://head:10001"\n')
    assert RecoveryConfig().ray is None and RecoveryConfig.from_file(path).ray == "ray://head:10001"
    path.write_text("[recovery]\nray = 1\n")
    with pytest.raises(IdapbcError, match="'ray' must be str"):
        RecoveryConfig.from_file(path)
    with pytest.raises(IdapbcError, match="ray must be"):
        RecoveryConfig(ray=" ")


@pytest.mark.parametrize("argv", [["recover", "{run}", "--ray", "auto"],
                                  ["train", "pendubot", "--recover", "auto", "--ray", "auto", "--out", "{run}"]])
def test_ray_flag_without_ray_installed_exits_2_with_one_line_naming_the_fix(argv, tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)  # as if not installed
    assert main([a.format(run=tmp_path) for a in argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Ray is not installed" in err[0] and INSTALL_HINT in err[0]
    assert not any(tmp_path.iterdir())  # refused before anything ran


def test_train_refuses_ray_without_the_recovery_stage(tmp_path, capsys):
    assert main(["train", "pendubot", "--ray", "auto", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--recover" in err[0] and "Fix" in err[0]
