"""A status that arrives after the SDK's timeout must not be taken for the next answer.

Protocol 2.0 status packets carry no sequence number and the SDK does not check a
read's length, so without care a late reply shifts every later answer by one.
"""

import pytest

from plantsim.hardware.dynamixel.driver import DynamixelTurntable
from plantsim.hardware.dynamixel.emulator import DynamixelEmulator
from plantsim.errors import ServoCommunicationError


@pytest.fixture
def emulator():
    # The bus clock holds a late status until the host's next packet: late by
    # construction, however long the scheduler keeps either thread waiting.
    with DynamixelEmulator(ids=(1,), clock="bus") as emu:
        yield emu


# Scheduler allowance on the protocol's status timeout (for an emulator thread the
# scheduler keeps waiting), s; a late status costs the driver one such wait.
ALLOWANCE_S = 0.5
LATE_S = 0.6


def test_late_reply_does_not_become_the_next_answer(emulator):
    with DynamixelTurntable(retries=0, scheduler_allowance_s=ALLOWANCE_S) as driver:
        driver.connect(emulator.port_path)
        driver.write_register("Homing Offset", 1000)
        emulator.inject_late_reply(1, delay_s=LATE_S)
        with pytest.raises(ServoCommunicationError, match="no status packet"):
            driver.read_register("Torque Enable")
        assert driver.read_register("Present Position") == 1000
        assert driver.read_register("Firmware Version") == 46


def test_late_reply_is_retried(emulator, caplog):
    with DynamixelTurntable(retries=2, scheduler_allowance_s=ALLOWANCE_S) as driver:
        driver.connect(emulator.port_path)
        driver.write_register("Homing Offset", 1000)
        emulator.inject_late_reply(1, delay_s=LATE_S)
        assert driver.read_register("Model Number") == 1020
        assert driver.read_register("Firmware Version") == 46
        assert "attempt 1 of 3" in caplog.text
        assert "discarded 1 late status packet(s)" in caplog.text


def test_late_reply_of_the_same_length_is_discarded_not_taken(emulator, caplog):
    """Two reads of the same register: only the resync tells the late status from the answer."""
    with DynamixelTurntable(retries=1, scheduler_allowance_s=ALLOWANCE_S) as driver:
        driver.connect(emulator.port_path)
        driver.write_register("Homing Offset", 1000)
        emulator.inject_late_reply(1, delay_s=LATE_S)
        assert driver.read_register("Homing Offset") == 1000  # answered on the retry
        driver.write_register("Homing Offset", 2000)
        assert driver.read_register("Homing Offset") == 2000  # not the late 1000
        assert "discarded 1 late status packet(s)" in caplog.text


def test_late_reply_on_the_wall_clock_is_retried(caplog):
    """On the wall clock the late status really leaves later than the driver waits.

    Whenever it comes (the scheduler decides), no answer is taken from the wrong
    request: every read below returns its own register.
    """
    with DynamixelEmulator(ids=(1,)) as emu, DynamixelTurntable(retries=3, scheduler_allowance_s=0.2) as driver:
        driver.connect(emu.port_path)
        driver.write_register("Homing Offset", 1000)
        emu.inject_late_reply(1, delay_s=0.5)
        assert driver.read_register("Homing Offset") == 1000
        assert driver.read_register("Firmware Version") == 46
        assert driver.read_register("Present Position") == 1000
        assert driver.read_register("Model Number") == 1020


def test_inject_late_reply_validates():
    with DynamixelEmulator(ids=(1,)) as emu:
        with pytest.raises(ValueError, match="delay_s must be finite and > 0"):
            emu.inject_late_reply(1, delay_s=0)
