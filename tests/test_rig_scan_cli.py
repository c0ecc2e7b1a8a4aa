"""``plantsim rig scan`` end to end against an emulator in this process."""

import json
import math


from plantsim.cli import app as cli
from plantsim.scan.journal import read_journal
from plantsim.turntable import units


def scan_args(emulator, cylinder, out, *extra):
    return ["rig", "scan", cylinder, "--port", emulator.port_path, "--baud", "57600", "--id", "1",
            "--step-deg", "30", "-o", str(out), "--retries", "5", "--status-timeout-ms", "1500", *extra]  # room for a starved emulator thread


def test_rig_scan_writes_cloud_and_sidecar_and_removes_the_journal(tmp_path, emulator, cylinder, capsys):
    out = tmp_path / "plant.ply"
    assert cli.main(scan_args(emulator, cylinder, out)) == 0, capsys.readouterr().err
    assert "from 12 lines x 683 beams (realistic sensor, hardware turntable, step mode) to" in capsys.readouterr().out
    side = json.loads((tmp_path / "plant.ply.json").read_text())
    turntable, lidar = side["simulated"]["turntable"], side["simulated"]["lidar"]
    assert turntable["kind"] == "dynamixel" and turntable["id"] == 1 and turntable["motion"] == "hardware"
    assert turntable["baud_bps"] == 57600 and lidar["kind"] == "simulated" and lidar["sensor"] == "realistic"
    assert side["config"]["scan"]["step_deg"] == 30
    assert out.exists() and not (tmp_path / "plant.ply.journal").exists()


def inject_when_goal_reaches(emulator, goal_deg, fault):
    """Injects ``fault`` once the servo is sent to ``goal_deg`` (checked every 5 ms of simulated time).

    On the bus clock this is a point of the scan, not of the wall clock: with 30 deg
    steps, the goal 90 deg is the 4th line's, written after 3 lines are journaled.
    """
    goal_ticks = units.rad_to_ticks(math.radians(goal_deg))

    def check():
        if emulator.servo(1).get("Goal Position") >= goal_ticks:
            fault()
        else:
            emulator.call_at(emulator.sim_time + 0.005, check)

    emulator.call_at(0.0, check)


def test_fault_exits_non_zero_with_how_to_resume_then_resume_completes(tmp_path, emulator, cylinder, capsys):
    out = tmp_path / "plant.las"
    journal = tmp_path / "plant.las.journal"
    inject_when_goal_reaches(emulator, 90, lambda: emulator.inject_no_reply(1, count=None))
    # The CLI's default retries: each costs a full status timeout on the silent servo (1 + 2 for the
    # lost poll; then the close's and the safety stop's 3 torque-off attempts, one ping and one write each).
    assert cli.main(scan_args(emulator, cylinder, out, "--retries", "2")) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert f"on {emulator.port_path} ID 1" in err[0] and "no status packet" in err[0]
    assert err[-1] == (f"plantsim: the lines taken are safe in {journal}; to continue, fix the cause and "
                       "run the same command again with --resume")
    done = len(read_journal(journal).lines)
    assert done == 3 and not out.exists()

    emulator.clear_faults()
    assert cli.main(scan_args(emulator, cylinder, out)) == 2  # without --resume: refused
    assert "holds an unfinished scan; run the same command with --resume" in capsys.readouterr().err
    assert cli.main(scan_args(emulator, cylinder, out, "--resume", "--keep-journal")) == 0, capsys.readouterr().err
    assert f"12 lines ({done} resumed from the journal)" in capsys.readouterr().out
    assert [line.index for line in read_journal(journal).lines] == list(range(12))
    side = json.loads((tmp_path / "plant.las.json").read_text())
    assert side["journal"] == {"path": str(journal), "kept": True, "lines_resumed": done}


def test_unreachable_servo_and_real_lidar_give_clear_errors(tmp_path, emulator, cylinder, capsys):
    out = tmp_path / "plant.ply"
    wrong_id = ["rig", "scan", cylinder, "--port", emulator.port_path, "--id", "7", "-o", str(out)]
    assert cli.main(wrong_id) == 1
    assert "ID 7 at 57600 bps failed" in capsys.readouterr().err
    assert cli.main(scan_args(emulator, cylinder, out, "--lidar", "urg")) == 2
    assert "--lidar urg needs --lidar-port PORT" in capsys.readouterr().err
    assert not (tmp_path / "plant.ply.journal").exists()


def test_rig_scan_writes_the_raw_bag_and_reconstruct_rebuilds_the_cloud(tmp_path, emulator, cylinder, capsys):
    from plantsim.cloud.bag import read_raw

    out, bag, again = tmp_path / "plant.las", tmp_path / "raw", tmp_path / "again.las"
    assert cli.main(scan_args(emulator, cylinder, out, "--raw", str(bag), "--seed", "4")) == 0, \
        capsys.readouterr().err
    raw, info = read_raw(bag)
    assert raw.n_lines == 12 and raw.intensity is not None and raw.angle_mode == "line"
    assert info["simulated"]["turntable"]["motion"] == "hardware"
    # The encoder log of a rig step scan is the servo's reported angle of each line.
    assert len(raw.encoder_angle_rad) == 12
    assert cli.main(["reconstruct", str(bag), "-o", str(again)]) == 0
    assert out.read_bytes() == again.read_bytes()


def test_rig_scan_refuses_settings_of_the_simulated_turntable_before_moving(tmp_path, emulator, cylinder, capsys):
    config = tmp_path / "rig.toml"
    config.write_text("[turntable.jitter]\nbacklash_deg = 0.5\n")
    out = tmp_path / "plant.las"
    assert cli.main(scan_args(emulator, cylinder, out, "--config", str(config))) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "[turntable.jitter] backlash_deg describes the simulated turntable" in err[0]
    assert not out.exists() and not (tmp_path / "plant.las.journal").exists()
    with emulator.lock:
        assert emulator.servo(1).shaft.position == 0.0  # it never moved
