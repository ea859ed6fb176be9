"""``sea-daemon bench loop``: a short run in real-time pace on the in-process device model (the
figures themselves are the benchmark's; here only that it runs and reports what it says)."""
import json

import pytest

from sea_daemon.apps import cli


def _bench_loop(tmp_path, capsys, bound_in):
    """A short ``bench loop --stages`` at 100 Hz on the virtual bus with the bound ``bound_in``:
    (printed output, its JSON); the run must succeed."""
    out_json = tmp_path / "loop.json"
    code = cli.main(["bench", "loop", "--rate", "100", "--cycles", "100", "--bus", "virtual", "--train", "300",
                     "--rt-priority", "0", "--stages", "--bound-in", bound_in, "--host-rounds", "10",
                     "--json", str(out_json)])
    out, _ = capsys.readouterr()
    assert code == 0, out
    return out, json.loads(out_json.read_text())


def test_bench_loop_reports_the_daemons_cpu_per_stage(tmp_path, capsys):
    out, data = _bench_loop(tmp_path, capsys, "loop")
    stages = data["stages_cpu_us"]
    assert set(stages) == {"read", "controller", "write", "actuated", "estimator (with its bound)", "bound",
                           "publication"}
    # every measured cycle went through each stage once (the start-up's priming read/write and
    # the first cycle are not counted)
    for label in ("read", "controller", "estimator (with its bound)", "publication"):
        assert stages[label]["calls"] >= 99 and stages[label]["median"] > 0, (label, stages[label])
    # the bound from the first filter step on (not while the differentiator's window fills)
    assert 90 <= stages["bound"]["calls"] < 99 and stages["bound"]["median"] > 0
    # the bound is a part of the estimator's step
    assert stages["bound"]["median"] < stages["estimator (with its bound)"]["median"]
    assert "loop thread CPU per stage" in out and data["fault"] == "NONE"
    # the loop thread's page faults after the first tenth of the run are counted (the figure is the
    # benchmark's: in this process Python's allocator may still map a page now and then)
    pf = data["loop_thread_page_faults"]
    assert pf["cycles"] == 90 and pf["minor"] >= 0 and pf["major"] >= 0
    assert f"page faults of the loop thread over cycles 10..100: {pf['minor']} minor" in out
    # the host's reference workload, before and after, one period's sleep before each round
    for w in (data["host_wake_before"], data["host_wake_after"]):
        assert w["samples"] == 10 and w["period_s"] == 0.01 and w["hot_us"] > 0 and w["after_sleep_us"] > 0
    assert "host: a fixed reference workload" in out


def test_host_wake_times_the_reference_right_after_the_sleep_and_hot():
    """The round: sleep one period, the reference timed (cold), run again, timed again (hot); the
    factor is the ratio of the medians.  A fake clock that advances 3 per call after a sleep and 1
    otherwise gives 3 against 1."""
    from sea_daemon.apps.bench import host_wake
    state = {"t": 0.0, "slept": False, "sleeps": []}

    def sleep(s):
        state["sleeps"].append(s)
        state["slept"] = True

    def clock():
        # each call ends one run of the reference: 3 s when it came right after a sleep
        state["t"] += 3.0 if state.pop("cold", False) else 1.0
        if state["slept"]:
            state["slept"] = False
            state["cold"] = True
        return state["t"]

    w = host_wake(0.004, 5, clock=clock, sleep=sleep)
    assert state["sleeps"] == [0.004] * 5
    assert w["after_sleep_us"] == pytest.approx(3e6) and w["hot_us"] == pytest.approx(1e6)
    assert w["factor"] == pytest.approx(3.0) and w["samples"] == 5
    with pytest.raises(ValueError, match="period must be > 0"):
        host_wake(0.0, 5)


def test_bench_loop_with_the_bound_worker_reports_its_cpu_and_the_bounds_age(tmp_path, capsys):
    out, data = _bench_loop(tmp_path, capsys, "worker")
    assert data["bound_in"] == "worker" and data["fault"] == "NONE"
    w = data["bound_worker"]
    # the worker took every filter step's sample; the ages are those of published bounds
    assert w["samples_done"] >= w["filter_steps"] >= 90 and w["cpu_per_sample_us"]["median"] > 0
    assert 0 <= w["age_cycles"]["median"] <= w["age_cycles"]["max"]
    assert 0 <= w["cycles_without_bound_within_max_age"] <= w["filter_steps"]
    # the loop's estimator step hands the bound over: no bound stage in the loop thread
    assert "bound" not in data["stages_cpu_us"]
    assert data["stages_cpu_us"]["estimator (filter, bound handed to the worker)"]["calls"] >= 99
    assert "the bound worker's process is not included" in out and "bound age" in out
    # its share of one CPU at the loop's rate (mean CPU per sample ÷ period), beside the kernel's
    # budget for real-time tasks (a worker busy past it stops every real-time task on its CPU)
    assert 0 < w["cpu_share"] <= w["cpu_per_sample_us"]["max"] * 1e-6 / 0.01
    budget = data["rt_budget"]
    with open("/proc/sys/kernel/sched_rt_runtime_us") as f:
        assert budget["runtime_us"] == int(f.read())
    if budget["runtime_us"] > 0:
        assert f"the kernel lets real-time tasks use {budget['runtime_us']} us of every" in out
        assert f"bound worker's share of one CPU at this rate: {w['cpu_share'] * 100:.0f} %" in out
        assert f"the worker gave SCHED_FIFO up for being behind {w['rt_yields']} times" in out
    assert w["rt_yields"] >= 0
    # how its counts reach the loop: shared memory on x86-64, the pipe elsewhere (and said so)
    from sea_daemon.runtime.bound_worker import counts_path
    assert w["counts"] == counts_path()
    assert ("through shared memory" if w["counts"] == "memory" else "through a pipe") in out
