"""bench loop's daemon CPU counts the CAN receive threads of every bus of a driver of several buses."""
import threading
import types

from sea_daemon.apps.bench.loop import ReceiveThreadsCpu


def _bus_with_reader(stop):
    t = threading.Thread(target=stop.wait, daemon=True)
    t.start()
    return types.SimpleNamespace(network=types.SimpleNamespace(notifier=types.SimpleNamespace(_readers=[t]))), t


def test_receive_threads_of_every_bus():
    stop = threading.Event()
    (a, ta), (b, tb) = _bus_with_reader(stop), _bus_with_reader(stop)
    # a driver of two buses, as CanopenBuses: its network is the first bus's
    hw = types.SimpleNamespace(subs=[a, b], network=a.network)
    try:
        assert len(ReceiveThreadsCpu(hw).clocks) == 2
        assert len(ReceiveThreadsCpu(a).clocks) == 1          # one bus: its own driver
        assert ReceiveThreadsCpu(hw).now() >= 0.0
    finally:
        stop.set()
        ta.join()
        tb.join()
