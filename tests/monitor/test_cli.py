"""The ``dexmon`` command line itself: --version, and that help and argument errors load
nothing heavy (no numba, no pyvista), so they answer at once."""

from __future__ import annotations

import subprocess
import sys

from monitor.cli import main, version


def test_version(capsys):
    try:
        main(["--version"])
    except SystemExit as exc:  # argparse's version action exits 0
        assert exc.code in (0, None)
    assert capsys.readouterr().out.strip() == f"dexmon {version()}"


def _heavy_modules_after(argv: list[str]) -> set[str]:
    code = ("import sys\nfrom monitor.cli import main\n"
            f"try:\n    main({argv!r})\nexcept SystemExit:\n    pass\n"
            "print(sorted(m for m in ('numba', 'pyvista', 'trimesh', 'matplotlib', 'vtk') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    return set(eval(out.stdout.strip().splitlines()[-1]))  # a list literal this test printed


def test_help_and_argument_errors_load_nothing_heavy(tmp_path):
    assert _heavy_modules_after(["--help"]) == set()
    assert _heavy_modules_after(["simulate", "--help"]) == set()
    assert _heavy_modules_after(["live", "--no-such-flag"]) == set()
    assert _heavy_modules_after(["simulate", str(tmp_path / "missing.nc"), "--stock", "box:0,0,0,1,1,1",
                                 "--tool", "ball:6"]) == set()


def test_a_missing_serial_device_is_said_before_anything_slow(tmp_path, capsys):
    from monitor.commands.dry_run import EXAMPLE_JOB

    missing = str(tmp_path / "ttyUSB9")
    for url in (f"grbl://{missing}", f"grbl+passthrough://{missing}", f"modbus+rtu://{missing}"):
        assert main(["live", str(EXAMPLE_JOB), "--controller", url, "--run", str(tmp_path / "r.sqlite")]) == 2
        err = capsys.readouterr().err
        assert "no such serial device" in err and missing in err, err
    assert not (tmp_path / "r.sqlite").exists()
    assert _heavy_modules_after(["live", str(EXAMPLE_JOB), "--controller", f"grbl://{missing}",
                                 "--run", str(tmp_path / "r.sqlite")]) == set()
