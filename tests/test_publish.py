"""Publication of the estimate: the client's wire format, the local socket, the daemon node's TPDOs and
its EDS (docs/can.md, docs/interfaces.md §6)."""
from __future__ import annotations

import math
import os
import socket
import struct
import subprocess
import sys
import time
import uuid

import numpy as np
import pytest

from sea_daemon import client
from sea_daemon.core.estimators.base import Estimate
from sea_daemon.errors import Fault, InputError
from _paths import repo_root


class Meas:
    def __init__(self, n, t=0.0):
        self.t, self.q = t, np.linspace(0.1, 0.2, n)


def estimate(n, hat=1.25, bound=0.5, valid=True) -> Estimate:
    e = Estimate.zeros(n)
    e.tau_h_act_hat[:] = hat + np.arange(n)
    e.tau_h_act_bound[:] = bound
    e.tau_h_act_sigma[:] = 0.1
    e.valid = valid
    return e


# ---------------------------------------------------------------------------- wire format
def test_datagram_roundtrip_and_refusals():
    buf = bytearray(client.record_size(2))
    client.encode_into(buf, 2, 7, 0.07, 12.5, 0, client.FLAG_ESTIMATOR, 0b01,
                       [(0.1, 1.0, 0.5, 0.2, 0.05, 0.3), (0.2, 2.0, -0.5, math.inf, 0.0, 0.0)])
    s = client.decode(bytes(buf))
    assert (s.cycle, s.t, s.joints, s.valid, s.fault_name) == (7, 0.07, 2, (True, False), "NONE")
    assert s.tau_h_act_bound == (0.2, math.inf) and s.tau_assist == (0.3, 0.0) and s.q == (0.1, 0.2)
    with pytest.raises(InputError, match="shorter than the header"):
        client.decode(b"xx")
    with pytest.raises(InputError, match="magic"):
        client.decode(b"XXXX" + bytes(buf[4:]))
    with pytest.raises(InputError, match="expected 136"):
        client.decode(bytes(buf[:-1]))


def test_tpdo_layout_and_decoding():
    assert client.tpdo_cob_ids(127, 3) == {"joint1": 0x1FF, "joint2": 0x3FF, "joint3": 0x4FF, "status": 0x2FF}
    d = client.decode_tpdo(0x1FF, struct.pack("<ff", 1.5, math.inf))
    assert d == {"joint": 1, "tau_h_act_hat": 1.5, "tau_h_act_bound": math.inf, "valid": False}
    d = client.decode_tpdo(0x2FF, struct.pack("<IHBB", 99, int(Fault.EMCY), 1, client.FLAG_FAULT))
    assert d["cycle"] == 99 and d["fault_name"] == "EMCY" and d["valid"][0] and d["flags"] == 1
    with pytest.raises(InputError, match="no TPDO of node 127"):
        client.decode_tpdo(0x181, bytes(8))
    with pytest.raises(InputError, match="allowed 1..127"):
        client.tpdo_cob_ids(0)


def test_client_imports_nothing_of_the_daemon():
    code = ("import sys; import sea_daemon.client; "
            "bad = [m for m in ('numpy', 'scipy', 'numba', 'can', 'canopen', 'sea_daemon.core', 'sea_daemon.hw', "
            "'sea_daemon.runtime') if m in sys.modules]; print(bad); sys.exit(1 if bad else 0)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       env={**os.environ, "PYTHONPATH": str(repo_root())})
    assert r.returncode == 0, r.stdout + r.stderr


# ---------------------------------------------------------------------------- local socket
@pytest.fixture
def sockpath(tmp_path_factory):
    d = tmp_path_factory.mktemp("s")
    p = d / "d.sock"
    if len(os.fsencode(str(p))) >= 100:
        p = f"/tmp/sea-test-{uuid.uuid4().hex[:8]}.sock"
    yield p
    if os.path.exists(p):
        os.unlink(p)


def publisher(path, n=1, controller=None):
    from sea_daemon.runtime.publish import LocalPublisher, Publisher
    loc = LocalPublisher(path, n)
    loc.poll_s = 0.0
    return Publisher(n, 0.01, local=loc, controller=controller)


def test_local_publication_every_cycle_inf_when_invalid(sockpath):
    pub = publisher(sockpath, 2)
    try:
        with client.Subscriber(sockpath) as sub:
            pub.publish(0, Meas(2, 0.0), None, np.zeros(2), 0)             # start-up: no estimate
            pub.publish(1, Meas(2, 0.01), estimate(2, valid=False), np.zeros(2), 0)
            pub.publish(2, Meas(2, 0.02), estimate(2), np.array([0.5, 0.6]), 0)
            pub.publish(3, Meas(2, 0.03), None, np.zeros(2), int(Fault.EMCY))
            # a sample the hardware missed: the angles the loop passed on (extrapolated), not meas.q
            pub.publish(4, Meas(2, 0.04), estimate(2), np.zeros(2), 0, np.array([0.3, 0.4]))
            got = [sub.receive(1.0) for _ in range(5)]
        assert [s.cycle for s in got] == [0, 1, 2, 3, 4]
        assert got[2].q == (0.1, 0.2) and got[4].q == (0.3, 0.4)
        assert got[0].tau_h_act_bound == (math.inf, math.inf) and got[0].valid == (False, False)
        assert got[1].tau_h_act_bound == (math.inf, math.inf) and got[1].tau_h_act_hat == (1.25, 2.25)
        assert got[2].tau_h_act_bound == (0.5, 0.5) and got[2].valid == (True, True) and got[2].tau_m == (0.5, 0.6)
        assert got[3].fault_name == "EMCY" and got[3].faulted and got[3].tau_h_act_bound[0] == math.inf
        assert all(not math.isnan(x) for s in got for x in s.tau_h_act_hat + s.tau_h_act_bound)
    finally:
        pub.close()
    assert not os.path.exists(sockpath)


def test_slow_reader_drops_counted_never_blocks(sockpath):
    pub = publisher(sockpath)
    try:
        sub = client.Subscriber(sockpath, buffer_bytes=4096)             # a reader that never reads
        pub.publish(0, Meas(1), estimate(1), np.zeros(1), 0)
        t0 = time.perf_counter()
        for k in range(1, 2000):
            pub.publish(k, Meas(1), estimate(1), np.zeros(1), 0)
        assert time.perf_counter() - t0 < 30                             # never waited on the reader
        assert pub.local.dropped > 0 and pub.errors == 0
        sub.sock.close()                                                 # the reader goes away
        pub.publish(2000, Meas(1), estimate(1), np.zeros(1), 0)
        pub.publish(2001, Meas(1), estimate(1), np.zeros(1), 0)
        assert pub.local.readers == 0 and pub.local.gone == 1
    finally:
        pub.close()


def test_stale_socket_replaced_live_one_refused(sockpath):
    from sea_daemon.runtime.publish import LocalPublisher
    s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    s.bind(str(sockpath))
    try:
        with pytest.raises(InputError, match="another process publishes there"):
            LocalPublisher(sockpath, 1)
    finally:
        s.close()
    assert os.path.exists(sockpath)                                      # left behind: stale
    LocalPublisher(sockpath, 1).close()
    with pytest.raises(InputError, match="no sea-daemon publishes"):
        client.Subscriber(sockpath)


def test_too_many_readers_refused(sockpath):
    pub = publisher(sockpath)
    pub.local.max_readers = 2
    subs = [client.Subscriber(sockpath) for _ in range(3)]
    try:
        pub.publish(0, Meas(1), estimate(1), np.zeros(1), 0)
        assert pub.local.readers == 2 and pub.local.refused == 1
    finally:
        for s in subs:
            s.close()
        pub.close()


# ---------------------------------------------------------------------------- CAN: TPDOs and the EDS
class FakeHw:
    def __init__(self, bus):
        import threading

        class Net:
            pass
        self.network = Net()
        self.network.bus = bus
        self.network.send_lock = threading.Lock()


def test_tpdos_decode_with_the_eds():
    """The frames the daemon sends, decoded by canopen from configs/eds/sea_daemon.eds alone."""
    import can
    import canopen

    from sea_daemon.hw.canopen_publish import TpdoPublisher
    from sea_daemon.runtime.publish import Publisher

    ch = f"pub-{uuid.uuid4().hex[:8]}"
    tx = can.Bus(interface="virtual", channel=ch)
    rx = can.Bus(interface="virtual", channel=ch)
    net = canopen.Network(rx)
    net.connect()
    try:
        node = canopen.RemoteNode(127, str(repo_root() / "configs" / "eds" / "sea_daemon.eds"))
        net.add_node(node)
        node.tpdo.read(from_od=True)
        got = []
        node.tpdo[1].add_callback(lambda m: got.append(("j1", m["Active human torque estimate.Joint 1"].raw,
                                                        m["Bound rho_k.Joint 1"].raw)))
        node.tpdo[3].add_callback(lambda m: got.append(("j2", m["Active human torque estimate.Joint 2"].raw,
                                                        m["Bound rho_k.Joint 2"].raw)))
        node.tpdo[2].add_callback(lambda m: got.append(("st", m["Cycle counter"].raw, m["Fault code"].raw,
                                                        m["Valid bits"].raw, m["Status flags"].raw)))
        pub = Publisher(2, 0.01, tpdo=TpdoPublisher(FakeHw(tx), 127, 2))
        pub.publish(5, Meas(2), estimate(2, hat=0.75, bound=0.25), np.zeros(2), 0)
        pub.publish(6, Meas(2), estimate(2, valid=False), np.zeros(2), 0)
        pub.publish(7, Meas(2), None, np.zeros(2), int(Fault.TPDO_MISSING))
        pub.publish(8, Meas(2), estimate(2, bound=1e39), np.zeros(2), 0)    # beyond REAL32: +inf
        deadline = time.monotonic() + 5
        while len(got) < 12 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert got[:3] == [("j1", 0.75, 0.25), ("j2", 1.75, 0.25), ("st", 5, 0, 0b11, client.FLAG_ESTIMATOR)]
        assert got[3][0] == "j1" and got[3][2] == math.inf and got[5][1:3] == (6, 0)
        assert got[6] == ("j1", 0.0, math.inf) and got[8][1:4] == (7, int(Fault.TPDO_MISSING), 0)
        assert got[8][4] & client.FLAG_FAULT
        assert got[9][2] == math.inf and got[11][3] == 0
        assert pub.tpdo.sent == 12 and pub.tpdo.dropped == 0 and pub.errors == 0
    finally:
        net.disconnect()
        tx.shutdown()


def test_publish_flag_of_the_bus_config():
    from sea_daemon.core.config import ModelConfig
    from sea_daemon.errors import ConfigError
    from sea_daemon.io.configfile import default_config_path, load_yaml
    raw = load_yaml(default_config_path())
    assert ModelConfig.from_dict(raw, "x").hardware.bus.publish is True
    raw["hardware"]["bus"] = {"publish": "yes"}
    with pytest.raises(ConfigError, match="hardware.bus.publish: must be true or false"):
        ModelConfig.from_dict(raw, "x")


def test_tpdo_cycles_pairs_each_tpdo1_with_its_status():
    frames = [(0x1FF, struct.pack("<ff", 1.0, 0.5)), (0x2FF, struct.pack("<IHBB", 7, 0, 1, 8)),
              (0x2FF, struct.pack("<IHBB", 8, 0, 1, 8)),                       # its TPDO1 was lost
              (0x1FF, struct.pack("<ff", 2.0, math.inf)), (0x2FF, struct.pack("<IHBB", 9, 3, 0, 9))]
    got = client.tpdo_cycles(frames)
    assert sorted(got) == [7, 9] and got[7][0]["tau_h_act_hat"] == 1.0 and got[9][1]["fault_name"] == "EMCY"


def test_watch_draws_band_estimate_assistance_and_invalid_cycles():
    from sea_daemon.apps.commands.watch import ASSIST, BAND, EST, INVALID, View

    def sample(k, valid=True, fault=0):
        return client.Sample(cycle=k, t=0.01 * k, t_mono=0.0, fault=fault, flags=client.FLAG_ASSIST_ON, valid=(valid,),
                             q=(0.5,), tau_m=(1.0,), tau_h_act_hat=(1.0,), tau_h_act_bound=(0.5 if valid else math.inf,),
                             tau_h_act_sigma=(0.1,), tau_assist=(-0.5 if valid else 0.0,))
    v = View(window=1.0, height=9, y_range=2.0)
    for k in range(100):
        v.add(sample(k, valid=k >= 20))
    lines = v.joint_lines(0, 60)
    plot = "\n".join(lines[1:-1])
    assert "valid" in lines[0] and "+1.000 N m" in lines[0]
    assert EST in plot and BAND in plot and ASSIST in plot and INVALID in plot
    v.add(sample(100, valid=False, fault=int(Fault.EMCY)))
    assert "NOT VALID" in v.joint_lines(0, 60)[0]
    assert "fault EMCY" in v.plain() and "inf" in v.plain()
