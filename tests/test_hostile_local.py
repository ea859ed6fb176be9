"""Hostile local users: another user's process cannot feed a reader forged estimates nor
subscribe unasked, no output replaces a device, FIFO or socket, an interrupted write leaves
nothing behind for long, a directory someone else owns is refused, and a killed daemon leaves
no shared memory.  (docs/safety.md, "Local security")"""
from __future__ import annotations

import json
import os
import signal
import socket
import stat
import subprocess
import sys
import time
import uuid

import pytest

from _cli import passive_log, refused, run
from _paths import repo_root
from sea_daemon.client import SUB_MAGIC, SUBSCRIBE, VERSION, Subscriber, encode_into
from sea_daemon.runtime.publish import LocalPublisher, ReaderPolicy

ROOT = repo_root()
CFG = str(ROOT / "configs" / "exo_1dof.yaml")
SIM_CFG = str(ROOT / "configs" / "exo_1dof_sim.yaml")
PASSIVE = str(ROOT / "configs" / "scenarios" / "passive.yaml")
NOBODY = 65534
as_root = pytest.mark.skipif(os.geteuid() != 0, reason="another user's process needs root to become user nobody")


def as_nobody(action) -> int:
    """Run ``action()`` in a forked child that became user nobody; its return value (0..255)."""
    pid = os.fork()
    if pid == 0:
        code = 99
        try:
            os.setgroups([])
            os.setgid(NOBODY)
            os.setuid(NOBODY)
            code = action()
        finally:
            os._exit(code)
    return os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1])


def forge(address, count: int = 20) -> int:
    """``count`` forged samples (valid, fault none, τ̂ 42 N m, bound 0.01 N m) to ``address``:
    how many the kernel refused."""
    buf = bytearray(112)
    encode_into(buf, 1, 10 ** 6, 1.0, 1.0, 0, 0, 1, [(0.0, 0.0, 42.0, 0.01, 0.01, 5.0)])
    s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    s.setblocking(False)                         # a full queue of the reader: not delivered, no wait
    refused_ = 0
    for _ in range(count):
        try:
            s.sendto(bytes(buf), address)
        except PermissionError:
            refused_ += 1
        except BlockingIOError:
            pass
    return refused_


def publish_one(pub: LocalPublisher, cycle: int) -> None:
    pub.poll(time.monotonic() + 1.0)
    encode_into(pub.buf, 1, cycle, 0.01 * cycle, time.monotonic(), 0, 0, 1, [(0.1, 0.2, 1.0, 0.5, 0.3, 0.0)])
    pub.send()


@pytest.fixture
def daemon_socket(tmp_path):
    pub = LocalPublisher(tmp_path / "sea-daemon.sock", 1)
    yield pub
    pub.close()


# ------------------------------------------------------------------ the published estimate
@as_root
def test_forged_datagrams_of_another_user_never_reach_a_reader(daemon_socket):
    with Subscriber(daemon_socket.path) as sub:
        publish_one(daemon_socket, 1)
        assert as_nobody(lambda: forge(sub.sock.getsockname())) == 20      # all refused by the kernel
        publish_one(daemon_socket, 2)
        got = [s for s in sub.samples(timeout=0.3)]
    assert [s.cycle for s in got] == [1, 2]
    assert all(s.tau_h_act_hat == (1.0,) for s in got)


@as_root
def test_a_forged_datagram_that_reaches_the_reader_is_dropped_and_counted(daemon_socket):
    """Should the reader's socket be unconnected (its daemon gone between the subscription's
    connect and send), the kernel's credentials of the sender still drop a forged datagram."""
    sub = Subscriber(daemon_socket.path)
    try:
        publish_one(daemon_socket, 1)
        assert sub.receive(1.0).cycle == 1
        daemon_socket.close()
        with pytest.raises(ConnectionRefusedError):
            sub.sock.send(b"x")                  # the peer is gone: the socket is unconnected now
        assert as_nobody(lambda: forge(sub.sock.getsockname(), 5)) == 0    # they arrive ...
        assert sub.receive(0.3) is None                                    # ... and are dropped
        assert sub.rejected == 5 and sub.received == 1
    finally:
        sub.sock.close()


@pytest.fixture
def reachable_dir():
    """A directory other users may pass through (mode 0711; pytest's tmp_path is root's alone)."""
    import shutil
    import tempfile
    d = tempfile.mkdtemp(prefix="sea-hostile-")
    os.chmod(d, 0o711)
    yield d
    shutil.rmtree(d)


@as_root
def test_the_daemon_subscribes_only_the_users_its_configuration_allows(reachable_dir):
    tmp_path = __import__("pathlib").Path(reachable_dir)
    def subscribe(path):
        def act():
            s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
            s.bind("")
            s.sendto(SUBSCRIBE.pack(SUB_MAGIC, VERSION, 0), str(path))
            return 0
        return act

    pub = LocalPublisher(tmp_path / "a.sock", 1, mode=0o666)        # the file lets anyone send
    try:
        assert as_nobody(subscribe(pub.path)) == 0
        pub.poll(time.monotonic() + 1.0)
        assert pub.readers == 0 and pub.foreign == 1
    finally:
        pub.close()
    pub = LocalPublisher(tmp_path / "b.sock", 1, readers=ReaderPolicy.from_config(users=["nobody"]))
    try:
        assert stat.S_IMODE(os.stat(pub.path).st_mode) == 0o666
        assert as_nobody(subscribe(pub.path)) == 0
        pub.poll(time.monotonic() + 1.0)
        assert pub.readers == 1 and pub.foreign == 0
    finally:
        pub.close()


def test_the_default_socket_is_the_daemon_users_alone(daemon_socket):
    assert stat.S_IMODE(os.stat(daemon_socket.path).st_mode) == 0o600


def test_an_unknown_reader_in_the_configuration_is_refused_by_name():
    from sea_daemon.errors import InputError
    with pytest.raises(InputError, match=r"hardware\.local_readers\.users: no user 'no-such-user-x'"):
        ReaderPolicy.from_config(users=["no-such-user-x"])


@pytest.mark.parametrize("value,expect", [
    ("{users: [[1]]}", r"hardware\.local_readers\.users: must be a list of user names or ids"),
    ("{groups: [-1]}", r"hardware\.local_readers\.groups: must be a list of group names or ids"),
    ("{others: [x]}", r"hardware\.local_readers\.others: unknown key; allowed: users, groups"),
    ("everyone", r"hardware\.local_readers: must be a mapping like"),
])
def test_a_bad_local_readers_setting_is_refused_with_its_key(tmp_path, capsys, value, expect):
    cfg = tmp_path / "m.yaml"
    cfg.write_text(_with_readers(value))
    log = passive_log(tmp_path / "log.csv")
    code, _, err = run(["replay", log, "--config", cfg, "--estimator", "akf", "--out", tmp_path / "e.csv"], capsys)
    refused(code, err, expect)


def _with_readers(value: str) -> str:
    import yaml
    d = yaml.safe_load(open(CFG).read())
    d.setdefault("hardware", {})["local_readers"] = yaml.safe_load(value)
    return yaml.safe_dump(d)


# ------------------------------------------------------------------ outputs
def _device(path):
    """A character device like /dev/null (mknod, as root), else a FIFO."""
    if os.geteuid() == 0:
        os.mknod(path, stat.S_IFCHR | 0o666, os.makedev(1, 3))
    else:
        os.mkfifo(path)


def _fifo(path):
    os.mkfifo(path)


def _socket(path):
    s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    s.bind(str(path))
    s.close()


@pytest.mark.parametrize("make,kind", [(_device, "character device|FIFO"), (_fifo, "FIFO"), (_socket, "socket")])
@pytest.mark.parametrize("via_link", [False, True])
def test_an_output_never_replaces_a_device_fifo_or_socket(tmp_path, capsys, make, kind, via_link):
    log = passive_log(tmp_path / "log.csv")
    target = tmp_path / "target"
    make(target)
    before = os.lstat(target)
    out = target
    if via_link:
        out = tmp_path / "link"
        out.symlink_to(target)
    code, _, err = run(["replay", log, "--config", CFG, "--estimator", "akf", "--out", out], capsys)
    refused(code, err, rf"--out .*: is a ({kind})", "replaces only a regular file")
    after = os.lstat(target)
    assert (after.st_ino, after.st_mode, after.st_rdev) == (before.st_ino, before.st_mode, before.st_rdev)
    assert not [p for p in os.listdir(tmp_path) if p.endswith(".tmp")]


def test_temporary_files_of_a_killed_write_are_removed_by_the_next_run(tmp_path, capsys):
    log = passive_log(tmp_path / "log.csv")
    stale = tmp_path / ".e.csv.ab1_cd9x.tmp"          # the writer's own pattern, before this process
    fresh = tmp_path / ".e.csv.zz9_yy8w.tmp"          # the same pattern, written after this process began
    other = tmp_path / ".e.csv.keep.tmp"              # not the pattern
    for p in (stale, fresh, other):
        p.write_text("partial")
    old = time.time() - 3600
    os.utime(stale, (old, old))
    os.utime(other, (old, old))
    code, _, err = run(["replay", log, "--config", CFG, "--estimator", "akf", "--out", tmp_path / "e.csv"], capsys)
    assert code == 0, err
    assert not stale.exists() and fresh.exists() and other.exists()


# ------------------------------------------------------------------ directories of others
@pytest.mark.parametrize("how", ["foreign owner", "world-writable"])
def test_an_ipc_bus_directory_someone_else_could_own_is_refused(how):
    if how == "foreign owner" and os.geteuid() != 0:
        pytest.skip("making a directory another user owns needs root")
    from sea_daemon.hw.ipc_bus import BASE_DIR
    channel = f"hostile-{uuid.uuid4().hex[:8]}"
    d = os.path.join(BASE_DIR, channel)
    os.makedirs(BASE_DIR, exist_ok=True)
    os.mkdir(d)
    try:
        if how == "foreign owner":
            os.chown(d, NOBODY, NOBODY)
        else:
            os.chmod(d, 0o777)
        p = subprocess.run([sys.executable, "-m", "sea_daemon", "device-model", "--bus", "ipc", "--channel", channel],
                           capture_output=True, text=True, timeout=120, cwd=ROOT,
                           env=dict(os.environ, PYTHONPATH=str(ROOT)))
        refused(p.returncode, p.stderr, "ipc bus channel", "owned by uid 65534" if how == "foreign owner"
                else "mode 0777 lets group or others write it")
        assert os.listdir(d) == []
    finally:
        for name in os.listdir(d):
            os.unlink(os.path.join(d, name))
        os.rmdir(d)


def test_a_log_directory_others_may_write_is_refused(tmp_path, capsys):
    logs = tmp_path / "logs"
    logs.mkdir()
    logs.chmod(0o777)
    code, _, err = run(["calibrate", "--config", SIM_CFG, "--scenario", PASSIVE, "--device-model", PASSIVE,
                        "--out", tmp_path / "m.npz", "--log-dir", logs, "--cycles", "10", "--no-progress"], capsys)
    refused(code, err, r"--log-dir .*logs: mode 0777 lets group or others write it")
    assert os.listdir(logs) == []


# ------------------------------------------------------------------ shared memory
def _wait_for(pred, timeout):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.1)
    return False


def _shm_names() -> set[str]:
    return set(os.listdir("/dev/shm")) if os.path.isdir("/dev/shm") else set()


def _started(logs, proc) -> bool:
    try:
        return json.loads((logs / "sea-daemon.pid").read_text())["pid"] == proc.pid
    except (OSError, ValueError, KeyError):
        return False


def _memfds(pid: int) -> int:
    n = 0
    for fd in os.listdir(f"/proc/{pid}/fd"):
        try:
            n += "memfd:sea-daemon" in os.readlink(f"/proc/{pid}/fd/{fd}")
        except OSError:
            pass
    return n


def test_a_killed_daemon_leaves_no_shared_memory_and_the_next_one_starts(tmp_path):
    model, logs = tmp_path / "model.npz", tmp_path / "logs"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    p = subprocess.run([sys.executable, "-m", "sea_daemon", "calibrate", "--config", SIM_CFG, "--scenario", PASSIVE,
                        "--device-model", PASSIVE, "--out", str(model), "--log-dir", str(tmp_path / "calib"),
                        "--cycles", "400", "--no-progress"], capture_output=True, text=True, env=env, cwd=ROOT,
                       timeout=600)
    assert p.returncode == 0, p.stderr
    cmd = [sys.executable, "-m", "sea_daemon", "run", "--config", SIM_CFG, "--model", str(model),
           "--device-model", PASSIVE, "--pace", "realtime", "--rt-priority", "0", "--overrun-streak", "0",
           "--log-dir", str(logs)]
    before = _shm_names()
    for attempt in ("killed", "stopped"):
        proc = subprocess.Popen(cmd, env=env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            assert _wait_for(lambda: _started(logs, proc) or proc.poll() is not None, 300)
            assert proc.poll() is None, proc.communicate()[1]
            assert _wait_for(lambda: _memfds(proc.pid) >= 1, 30)          # its shared memory: no name anywhere
            assert not {n for n in _shm_names() - before if n.startswith("psm_")}
            proc.send_signal(signal.SIGKILL if attempt == "killed" else signal.SIGTERM)
            _, err = proc.communicate(timeout=120)       # until every child of it has closed stderr
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
        assert "leaked shared_memory" not in err, err
        assert not {n for n in _shm_names() - before if n.startswith("psm_")}
        assert proc.returncode == (-9 if attempt == "killed" else 0), err
