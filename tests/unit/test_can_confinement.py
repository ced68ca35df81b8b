"""CAN fault confinement (ISO 11898-1), hand-counted: +8 TEC per transmit error, +1 REC per receive
error (+8 for the first to flag), -1 per good frame, error-passive at 128, bus-off at 256."""

from teleop.can.confinement import ErrorCounters


def test_transmit_errors_go_passive_at_16_and_bus_off_at_32():
    c = ErrorCounters()
    states = [c.tx_error() for _ in range(32)]
    assert states[:15] == ["error_active"] * 15  # TEC 8..120
    assert states[15:31] == ["error_passive"] * 16  # TEC 128..248
    assert states[31] == "bus_off" and c.tec == 256


def test_good_frames_count_down_and_receive_errors_alone_never_bus_off():
    c = ErrorCounters()
    for _ in range(10):
        c.tx_error()
    for _ in range(30):
        c.tx_ok()
    assert c.tec == 50
    for _ in range(10_000):
        c.rx_error()
    assert c.state == "error_passive" and c.rec == 10_000  # receive errors never take a node off
    c.rx_ok()
    assert c.rec == 127 and c.state == "error_active"  # from above 127 back into 119..127
    assert c.rx_error(first_to_flag=True) == "error_passive" and c.rec == 135


def test_bus_off_is_latched_and_reported_counters_are_believed():
    c = ErrorCounters()
    assert c.set(200, 3) == "error_passive" and (c.tec, c.rec) == (200, 3)
    assert c.bus_off() == "bus_off"
    c.tx_ok()
    c.set(0, 0)
    assert c.state == "bus_off"  # recovery is a restart, not modelled
