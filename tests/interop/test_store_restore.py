"""Store and restore on a virtual device through `candeck od`, and saved
values surviving a restart of `candeck vbus --data-dir` (issue: virtual
devices)."""

import subprocess

from conftest import BIN, Vbus

SAVE = str(int.from_bytes(b"save", "little"))
LOAD = str(int.from_bytes(b"load", "little"))


def od(vbus, *args):
    proc = subprocess.run(
        [BIN, "od", args[0], "--bus", vbus.spec, "--node", "2", *args[1:]],
        capture_output=True,
        text=True,
        timeout=30,
    )
    return proc.returncode, proc.stdout.strip(), proc.stderr.strip()


def test_saved_values_survive_a_restart_of_vbus(tmp_path):
    vbus = Vbus("--devices", "jmc@2", "--data-dir", str(tmp_path))
    try:
        assert od(vbus, "read", "0x1017", "0", "--type", "u16")[1] == "1000"
        assert od(vbus, "write", "0x1017", "0", "250", "--type", "u16")[0] == 0
        status, _, err = od(vbus, "write", "0x1010", "1", "12345", "--type", "u32")
        assert status == 1 and "0x08000020" in err, err
        assert od(vbus, "write", "0x1010", "1", SAVE, "--type", "u32")[0] == 0
    finally:
        vbus.stop()
    assert (tmp_path / "devices" / "jmc-2.json").exists()

    vbus = Vbus("--devices", "jmc@2", "--data-dir", str(tmp_path))
    try:
        assert od(vbus, "read", "0x1017", "0", "--type", "u16")[1] == "250"
        # Back to the factory value, which is then what a restart keeps.
        assert od(vbus, "write", "0x1011", "1", LOAD, "--type", "u32")[0] == 0
        assert od(vbus, "read", "0x1017", "0", "--type", "u16")[1] == "1000"
    finally:
        vbus.stop()

    vbus = Vbus("--devices", "jmc@2", "--data-dir", str(tmp_path))
    try:
        assert od(vbus, "read", "0x1017", "0", "--type", "u16")[1] == "1000"
    finally:
        vbus.stop()


def test_store_is_refused_outside_pre_operational():
    vbus = Vbus("--devices", "jmc@2")
    try:
        proc = subprocess.run(
            [BIN, "nmt", "--bus", vbus.spec, "--node", "2", "start"], capture_output=True, text=True, timeout=30
        )
        assert proc.returncode == 0, proc.stderr
        status, _, err = od(vbus, "write", "0x1010", "1", SAVE, "--type", "u32")
        assert status == 1 and "0x08000021" in err, err
    finally:
        vbus.stop()
