"""Malformed cell profiles through ``weldcell profiles validate``, ``profiles list`` and ``run``:
each refused with one line and a fix, exit 3, no traceback (no RecursionError on a deep chain)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from .conftest import assert_refused, run_cli

REPO = Path(__file__).resolve().parents[2]
GOOD = (REPO / "profiles" / "cell1-scan-and-plan-sim.toml").read_bytes()
MINIMAL = b'schema = "weldcell/profile@1"\nname = "t"\n[job]\nname = "scan-and-plan"\n'


def chain(depth: int):
    """``p0.toml`` extends ``p1.toml`` ... extends ``p<depth>.toml`` (the last a whole profile)."""

    def make(folder: Path) -> Path:
        for i in range(depth):
            (folder / f"p{i}.toml").write_bytes(f'extends = "p{i + 1}.toml"\nname = "p{i}"\n'.encode())
        (folder / f"p{depth}.toml").write_bytes(MINIMAL)
        return folder / "p0.toml"

    return make


def files(main: bytes, **others: bytes):
    def make(folder: Path) -> Path:
        for name, data in others.items():
            (folder / f"{name}.toml").write_bytes(data)
        (folder / "p.toml").write_bytes(main)
        return folder / "p.toml"

    return make


def extends(target: str) -> bytes:
    return f'extends = "{target}"\nname = "child"\n'.encode()


PROFILE_CASES = {
    "invalid-utf8": (files(GOOD.replace(b"# Cell 1", b"# Cell \xff\xfe 1")), "not UTF-8"),
    "binary": (files(bytes(np.random.default_rng(5).integers(0, 256, 4000, dtype=np.uint8))), "not UTF-8"),
    "utf16": (files(GOOD.decode().encode("utf-16")), "not UTF-8"),
    "nul-bytes": (files(MINIMAL + b"\x00\x00"), "not valid TOML"),
    "toml-syntax": (files(MINIMAL + b"[job\nname = 1\n"), "not valid TOML"),
    "duplicate-key": (files(MINIMAL + b'name = "again"\n'), "not valid TOML"),
    "empty": (files(b""), "name"),
    "extends-3000": (chain(3000), "deeper than 32"),
    "extends-40": (chain(40), "deeper than 32"),
    "extends-cycle": (files(extends("q.toml"), q=extends("p.toml")), "cycle"),
    "extends-self": (files(extends("p.toml")), "cycle"),
    "extends-missing": (files(extends("absent.toml")), "base profile not found"),
    "extends-number": (files(b'extends = 5\nname = "x"\n'), "is not a file name"),
    "extends-empty": (files(b'extends = ""\nname = "x"\n'), "is not a file name"),
    "extends-list": (files(b'extends = ["a.toml"]\nname = "x"\n'), "is not a file name"),
    "extends-binary": (files(extends("b.toml"), b=bytes(range(256))), "not UTF-8"),
    "extends-bad-toml": (files(extends("b.toml"), b=b"[[[\n"), "not valid TOML"),
    "nested-arrays": (files(MINIMAL + b"deep = " + b"[" * 5000 + b"]" * 5000 + b"\n"), "nested"),
    "nested-tables": (files(MINIMAL + b"[" + b".".join([b"a"] * 200) + b"]\nx = 1\n"), "nested deeper"),
    "unknown-key": (files(MINIMAL + b'colour = "red"\n'), "colour"),
    "job-string": (files(b'schema = "weldcell/profile@1"\nname = "x"\njob = "scan-and-plan"\n'), "job"),
    "wrong-schema": (files(MINIMAL.replace(b"profile@1", b"profile@7")), "unsupported schema"),
    "too-large": (files(MINIMAL + b"#" * (5 << 20) + b"\n"), "is no profile"),
}


@pytest.mark.parametrize("case", sorted(PROFILE_CASES))
def test_profiles_validate_refuses_a_malformed_profile(tmp_path, capfd, case):
    make, words = PROFILE_CASES[case]
    f = make(tmp_path)
    assert_refused(capfd, ["profiles", "validate", f], 3, words, marker="✗")


@pytest.mark.parametrize("case", ["invalid-utf8", "binary", "extends-3000", "toml-syntax", "nested-arrays"])
def test_run_refuses_a_malformed_profile(tmp_path, capfd, case):
    make, words = PROFILE_CASES[case]
    f = make(tmp_path)
    assert_refused(capfd, ["run", f, "--runs-dir", tmp_path / "runs"], 3, words)
    assert not any((tmp_path / "runs").glob("*/result.json"))


def test_profiles_validate_prints_the_fix(tmp_path, capfd):
    (tmp_path / "p.toml").write_bytes(MINIMAL + b'colour = "red"\n')
    text = assert_refused(capfd, ["profiles", "validate", tmp_path / "p.toml"], 3, "colour", marker="✗")
    assert "fix: fix the keys listed" in text
    code, output, _, _ = run_cli(
        capfd, "profiles", "validate", REPO / "profiles" / "cell1-scan-and-plan-sim.toml"
    )
    assert code == 0, output


def test_profiles_list_reports_a_broken_file_in_its_row_and_goes_on(tmp_path, capfd):
    (tmp_path / "a-good.toml").write_bytes(GOOD)
    (tmp_path / "b-utf8.toml").write_bytes(b'name = "\xff"\n')
    (tmp_path / "c-syntax.toml").write_bytes(b"[job\n")
    (tmp_path / "d-binary.toml").write_bytes(bytes(range(256)))
    (tmp_path / "e-job-string.toml").write_bytes(
        b'name = "x"\njob = "scan-and-plan"\ndescription = "[red]x"\n'
    )
    (tmp_path / "f-good.toml").write_bytes(MINIMAL)
    code, output, native, _ = run_cli(capfd, "profiles", "list", tmp_path)
    assert code == 3 and "Traceback" not in output and native == ""
    text = " ".join(output.split())
    squeezed = "".join(output.split())
    for name in ("a-good", "b-utf8", "c-syntax", "d-binary", "e-job-string", "f-good"):
        assert f"{name}.toml" in squeezed, output  # every file has its row
    for name in ("b-utf8", "c-syntax", "d-binary"):
        # the row names the file and says it is an error (a narrow console may wrap a long path)
        assert f"{name}.tomlerror:" in squeezed.replace(f"✗{tmp_path}/", ""), output
    assert "scan-and-plan" in text and "[red]x" in text  # good rows listed; markup in a file is not obeyed
    assert "3 profile(s) could not be read" in text and "fix:" in text
    assert_refused(capfd, ["profiles", "list", tmp_path / "absent"], 2, "not found")
