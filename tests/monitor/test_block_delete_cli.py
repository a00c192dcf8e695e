"""The block delete switch from the command line and the job file (issue 13): '/' lines
run unless ``--block-delete`` or ``[program] block_delete = true`` turns the switch on."""

from __future__ import annotations

import json

import pytest

from monitor.cli import main
from monitor.job import JobError, load_job

PROGRAM = "G21 G90\nG0 X0 Y0 Z5\n/G1 X10 F100\nG1 Y10 F100\nM2\n"


@pytest.fixture
def prog(tmp_path):
    p = tmp_path / "slash.ngc"
    p.write_text(PROGRAM)
    return p


def _moves(capsys, *argv):
    assert main(["moves", *map(str, argv)]) == 0
    return [json.loads(ln) for ln in capsys.readouterr().out.splitlines()]


def test_moves_runs_slash_lines_unless_block_delete(prog, capsys):
    ran = _moves(capsys, prog)
    assert [r["line"] for r in ran if r["kind"] == "feed"] == [3, 4]
    skipped = _moves(capsys, prog, "--block-delete")
    assert [r["line"] for r in skipped if r["kind"] == "feed"] == [4]


def test_job_key_and_flag(prog, tmp_path):
    from monitor.job import add_job_arguments, job_from_args
    from monitor.program_moves import load_moves

    job_file = tmp_path / "job.toml"
    job_file.write_text(f'[program]\npath = "{prog.name}"\n')
    assert load_job(job_file).block_delete is False
    job_file.write_text(f'[program]\npath = "{prog.name}"\nblock_delete = true\n')
    job = load_job(job_file)
    assert job.block_delete is True
    moves, _ = load_moves(job)
    assert 3 not in moves["line"].tolist()
    job_file.write_text(f'[program]\npath = "{prog.name}"\nblock_delete = "yes"\n')
    with pytest.raises(JobError, match="block_delete.*true or false"):
        load_job(job_file)

    import argparse

    parser = argparse.ArgumentParser()
    add_job_arguments(parser)
    job_file.write_text(f'[program]\npath = "{prog.name}"\n')
    assert job_from_args(parser.parse_args([]), job_file).block_delete is False
    job = job_from_args(parser.parse_args(["--block-delete"]), job_file)
    assert job.block_delete is True
    moves, _ = load_moves(job)
    assert 3 not in moves["line"].tolist()


def test_simulate_block_delete(prog, capsys):
    def moves(*extra):
        rc = main(["simulate", str(prog), "--stock", "box:-5,-5,-5,15,15,0", "--tool", "flat:2",
                   "--resolution", "1", "--json", "--no-checks", *extra])
        assert rc == 0
        return json.loads(capsys.readouterr().out)["moves"]

    assert moves() == moves("--block-delete") + 1
