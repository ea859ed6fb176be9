"""One configuration at 100 Hz and 1 kHz (sea_daemon.core.rates), the model file's rate rule,
the ipc bus (sea_daemon.hw.ipc_bus) and the device model's answer statistics."""
from __future__ import annotations

import dataclasses
import os
import time
import uuid

import can
import numpy as np
import pytest

from sea_daemon.core.rates import at_rate, same_in_time, window_at
from sea_daemon.errors import InputError, ModelFileError
from sea_daemon.io.configfile import load_config
from _paths import repo_root

CFG = repo_root() / "configs" / "exo_1dof_sim.yaml"


def test_at_rate_keeps_the_differentiators_span_and_the_information_per_second():
    cfg = load_config(CFG)                      # 100 Hz, savgol W = 5, degree 2
    c1k = at_rate(cfg, 1000)
    assert c1k.rate_hz == 1000 and c1k.dt == pytest.approx(1e-3)
    assert c1k.kinematics.window == 41          # (W − 1)·dt: 40 ms at both rates
    assert (c1k.kinematics.window - 1) * c1k.dt == pytest.approx((cfg.kinematics.window - 1) * cfg.dt)
    np.testing.assert_allclose(c1k.estimator.R, 10 * cfg.estimator.R)
    assert c1k.estimator.nis_window == 10 * cfg.estimator.nis_window
    assert c1k.estimator.Sigma_nom_dt == cfg.estimator.Sigma_nom_dt and c1k.model == cfg.model
    assert at_rate(cfg, None) is cfg and at_rate(cfg, 100.0) is cfg
    back = at_rate(c1k, 100)
    assert back.kinematics == cfg.kinematics
    np.testing.assert_allclose(back.estimator.R, cfg.estimator.R)
    ma = dataclasses.replace(cfg.kinematics, method="ma", window=5)
    assert window_at(ma, 100, 1000) == 50
    assert same_in_time(cfg, c1k) and not same_in_time(cfg, dataclasses.replace(c1k, kinematics=cfg.kinematics))
    with pytest.raises(InputError, match="kinematics.window would be"):
        at_rate(cfg, 5000)


def test_a_model_file_of_100_hz_loads_at_1_khz_and_a_changed_window_is_refused(tmp_path):
    from sea_daemon.io.gpmodel import load_gp_model
    from _model import small_model
    cfg = load_config(CFG)
    p = tmp_path / "m.npz"
    res = small_model(cfg, p, residual=0.1)
    r, _ = load_gp_model(p, at_rate(cfg, 1000))
    assert r.n_points == res.n_points
    wrong = dataclasses.replace(at_rate(cfg, 1000), kinematics=cfg.kinematics)     # W = 5 at 1 kHz
    with pytest.raises(ModelFileError, match="kinematics|rate_hz"):
        load_gp_model(p, wrong)


# ------------------------------------------------------------------ the ipc bus
def _msg(i, data=b"\x01\x02"):
    return can.Message(arbitration_id=i, data=data, is_extended_id=False)


def test_ipc_bus_is_a_broadcast_bus_with_filters_applied_by_the_senders():
    from sea_daemon.hw.ipc_bus import IpcBus
    ch = f"t-{uuid.uuid4().hex[:8]}"
    a, b, c = IpcBus(ch), IpcBus(ch), IpcBus(ch, receive_own_messages=True)
    try:
        a.send(_msg(0x181, b"\x11" * 8))
        for bus in (b, c):
            m = bus.recv(1.0)
            assert m.arbitration_id == 0x181 and bytes(m.data) == b"\x11" * 8 and m.dlc == 8
        assert a.recv(0.05) is None                              # not its own frame
        c.send(_msg(0x80, b""))
        assert a.recv(1.0).arbitration_id == 0x80 and c.recv(1.0).arbitration_id == 0x80
        assert b.recv(1.0).arbitration_id == 0x80
        # b takes 0x182 only: the others' frames are not even sent to it
        b.set_filters([{"can_id": 0x182, "can_mask": 0x7FF, "extended": False}])
        assert os.path.exists(b.path + ".filter")
        time.sleep(0.01)
        for _ in range(30):                                       # more than a socket queues (10)
            a.send(_msg(0x701, b"\x05"))
        a.send(_msg(0x182, b"\x22" * 4))
        m = b.recv(1.0)
        assert m.arbitration_id == 0x182 and b.recv(0.0) is None       # b's queue held its frame only
        assert a.overruns > 0                      # c (no filter, not reading) lost what its queue could not hold
    finally:
        for bus in (a, b, c):
            bus.shutdown()
    assert not os.listdir(os.path.dirname(a.path))


def test_ipc_bus_reaches_members_that_join_between_two_sends():
    """Members that join after a send, two in the same instant, get the next frame (the
    channel's membership count in shared memory, not the directory's coarse mtime); one that
    leaves is no longer sent to."""
    from sea_daemon.hw.ipc_bus import IpcBus
    ch = f"t-{uuid.uuid4().hex[:8]}"
    a = IpcBus(ch)
    others = []
    try:
        a.send(_msg(0x80))                                         # nobody there yet
        others = [IpcBus(ch), IpcBus(ch)]
        a.send(_msg(0x181, b"\x07"))
        for bus in others:
            m = bus.recv(1.0)
            assert m is not None and m.arbitration_id == 0x181 and bytes(m.data) == b"\x07"
        gone = others.pop()
        gone.shutdown()
        a.send(_msg(0x182))
        assert [p for p, _ in a._peers] == [others[0].path]
    finally:
        for bus in [a, *others]:
            bus.shutdown()


def test_ipc_bus_member_answers_a_newcomers_first_frame_and_rejoins_a_channel_made_again():
    """A member answers a newcomer's first frame (the newcomer counted itself in before it
    sent); the channel's directory removed under a member and made again by a newcomer: within
    0.25 s the member has joined it anew and the two hear each other."""
    import shutil
    from sea_daemon.hw.ipc_bus import MEMBERS_FILE, IpcBus
    ch = f"t-{uuid.uuid4().hex[:8]}"
    a = IpcBus(ch)
    b = c = None
    try:
        a.send(_msg(0x80))                                         # a's list made: nobody there
        b = IpcBus(ch)
        b.send(_msg(0x701, b"\x00"))                               # b's boot-up
        assert a.recv(1.0).arbitration_id == 0x701
        a.send(_msg(0x601, b"\x40"))                               # a's answer reaches b
        assert b.recv(1.0).arbitration_id == 0x601
        b.shutdown()
        b = None
        shutil.rmtree(os.path.dirname(a.path))
        c = IpcBus(ch)
        time.sleep(0.3)
        a.send(_msg(0x181, b"\x01"))                               # a finds the directory gone: rejoins
        m = c.recv(1.0)
        assert m is not None and m.arbitration_id == 0x181
        c.send(_msg(0x182, b"\x02"))
        m = a.recv(1.0)
        assert m is not None and m.arbitration_id == 0x182
        assert os.path.exists(os.path.join(os.path.dirname(a.path), MEMBERS_FILE))
    finally:
        for bus in (a, b, c):
            if bus is not None:
                bus.shutdown()
    assert not os.listdir(os.path.dirname(a.path))              # the last one out removed the count


def test_ipc_bus_forgets_a_member_that_went_away():
    from sea_daemon.hw.ipc_bus import IpcBus
    ch = f"t-{uuid.uuid4().hex[:8]}"
    a, b = IpcBus(ch), IpcBus(ch)
    b._sock.close()                                  # gone without shutdown: the file stays, nobody reads
    a.send(_msg(0x80))
    assert all(p != b.path for p, _ in a._peers) and not os.path.exists(b.path)
    a.send(_msg(0x80))
    a.shutdown()


def test_make_bus_opens_ipc_and_a_remote_channel_is_still_checked():
    from sea_daemon.hw.bus import make_bus
    from sea_daemon.hw.ipc_bus import IpcBus
    from sea_daemon.core.config import BusConfig
    b = BusConfig.from_dict({"interface": "ipc", "channel": f"t-{uuid.uuid4().hex[:8]}"}, 1, "test")
    bus = make_bus(b)
    try:
        assert isinstance(bus, IpcBus)
    finally:
        bus.shutdown()


def test_device_model_reports_its_answer_latency_and_frames():
    from _hil import hil_config, hil_rig
    rig = hil_rig(hil_config("ipc"))
    try:
        rig.hw.start()
        for _ in range(20):
            rig.hw.read()
            rig.hw.write(np.zeros(1))
        st = rig.device_model.answer_stats()
    finally:
        rig.stop()
    assert st["syncs"] >= 20 and st["frames"] > 60 and st["data_bytes"] > 0
    assert 0 < st["answer_us"]["median"] < 1e6 and st["handler_cpu_us"]["median"] > 0
    # the slow answers with their cycle (bench loop's overrun causes): [cycle, answer, CPU] in µs
    slow = st["slow_answers"]
    assert isinstance(slow, list) and all(len(s) == 3 and 1 <= s[0] <= st["syncs"] and s[1] > 400 for s in slow)


def test_on_ipc_the_devices_filter_the_daemons_tpdos_out_and_read_takes_heartbeats_and_emcy():
    from _hil import hil_config, hil_rig
    rig = hil_rig(hil_config("ipc"))
    try:
        rig.hw.start()
        dev = rig.device_model.bus
        net = rig.hw._bus                                 # the canopen network's handle
        net._refresh()
        acc = {p: a for p, a in net._peers}[dev.path]      # the device model's published filter

        def accepted(i):
            return any(i & m == c & m for c, m in acc)
        node = rig.hw.bus_cfg.master_node
        assert not any(accepted(f + node) for f in (0x180, 0x280, 0x380, 0x480))    # the daemon's TPDOs
        assert all(accepted(i) for i in (0x000, 0x080, 0x601, 0x700 + node))
        # the drive's RPDO on the model's handle that nobody waits on (taken at the next SYNC)
        tap = {p: a for p, a in net._peers}[rig.device_model._rpdo_taps[0].path]
        assert not accepted(0x201) and any(0x201 & m == c & m for c, m in tap)
        assert not any(i & m == c & m for c, m in tap for i in (0x000, 0x080, 0x601, 0x700 + node))
        # heartbeats and EMCY: on the loop thread's handles (the heartbeats' own, the EMCY with the
        # TPDOs), no longer on the network's
        nodes = rig.hw.bus_cfg.drive_node + rig.hw.bus_cfg.encoder_node
        ids = {0x700 + i for i in nodes}
        emcy = {0x80 + i for i in nodes}
        assert rig.hw._hb_tap is not None and rig.hw._hb_tap.cob_ids == ids
        tpdo_accept = rig.hw._rx.bus._accept
        assert {i for i, _ in tpdo_accept} == emcy | {s.cob_id for s in rig.hw._rx.slots}
        assert not any((i & m) == (c & m) for i in ids | emcy for c, m in net._accept)
        t0 = time.monotonic()
        for _ in range(10):
            rig.hw.read()
            rig.hw.write(np.zeros(1))
            time.sleep(0.01)
        assert all(rig.hw._hb_last[i - 0x700] > t0 for i in ids)
    finally:
        rig.stop()


def test_one_poll_says_which_receive_handles_have_frames_queued():
    """sea_daemon.hw.canopen_rx.Queued: one poll for the cycle's receive handles (the driver's TPDO
    handle and its two taps); a handle with no descriptor (virtual) gives None: read as before."""
    import can
    from sea_daemon.hw.canopen_rx import Queued
    from sea_daemon.hw.ipc_bus import IpcBus
    ch = f"t-{uuid.uuid4().hex[:8]}"
    tx, a, b, c = IpcBus(ch), IpcBus(ch), IpcBus(ch), IpcBus(ch)
    v = can.Bus(interface="virtual", channel=f"q-{uuid.uuid4().hex[:6]}")
    try:
        assert Queued.of([a, v]) is None
        q = Queued.of([a, b, c])
        assert q.mask() == 0
        c.set_filters([{"can_id": 0x81, "can_mask": 0x7FF, "extended": False}])
        b.set_filters([{"can_id": 0x701, "can_mask": 0x7FF, "extended": False}])
        a.set_filters([{"can_id": 0x181, "can_mask": 0x7FF, "extended": False}])
        tx.send(_msg(0x81, b"\x00" * 8))
        time.sleep(0.01)
        assert q.mask() == 4                         # the third handle only
        tx.send(_msg(0x181, b"\x01"))
        time.sleep(0.01)
        assert q.mask() == 5
        assert a.recv_frame(0.0)[0] == 0x181 and c.recv_frame(0.0)[0] == 0x81
        assert q.mask() == 0
    finally:
        v.shutdown()
        for bus in (tx, a, b, c):
            bus.shutdown()


def test_ipc_recv_frame_reads_the_rest_of_a_burst_without_waiting(monkeypatch):
    """recv_frame(timeout, ready=True): a frame queued is read at once (no select before it);
    none queued: it waits as without the hint (the frame that comes within the timeout, or None)."""
    from sea_daemon.hw import ipc_bus
    from sea_daemon.hw.ipc_bus import IpcBus
    ch = f"t-{uuid.uuid4().hex[:8]}"
    tx, rx = IpcBus(ch), IpcBus(ch)
    waits = []
    real_select = ipc_bus.select.select

    def counting_select(*a):
        waits.append(a[-1])
        return real_select(*a)
    monkeypatch.setattr(ipc_bus.select, "select", counting_select)
    try:
        tx.send(_msg(0x181, bytes(range(8))))
        tx.send(_msg(0x182, b"\x01\x02\x03\x04"))
        time.sleep(0.01)
        got = rx.recv_frame(0.5)                              # no hint: waits first
        assert got[0] == 0x181 and bytes(got[1]) == bytes(range(8)) and len(waits) == 1
        got = rx.recv_frame(0.5, True)                        # the rest of the burst: no wait
        assert got[0] == 0x182 and bytes(got[1]) == b"\x01\x02\x03\x04" and len(waits) == 1
        assert rx.recv_frame(0.02, True) is None and len(waits) >= 2     # none left: waited
        assert rx.recv_frame(0.0, True) is None                          # none queued, no timeout
    finally:
        for bus in (tx, rx):
            bus.shutdown()
