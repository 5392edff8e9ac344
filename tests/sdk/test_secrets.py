"""No ``${env:NAME}`` secret's value in any output (docs/runs.md): the devices listing, ``profiles validate``,
``run`` errors, result.json provenance, state.json, logs, the report and summary, artefacts, the dry-run
log. Each channel records the reference (``${env:NAME}``) instead, and credentials in URLs are masked."""

from __future__ import annotations

import logging
import textwrap
from pathlib import Path

import pytest
from click.testing import CliRunner
from pydantic import Field
from weldcell.sdk import secrets
from weldcell.sdk.artifacts import read_json
from weldcell.sdk.cli import main
from weldcell.sdk.descriptors import DeviceRole, DeviceSpec, JobSpec
from weldcell.sdk.errors import DeviceError
from weldcell.sdk.hookspecs import hookimpl
from weldcell.sdk.settings import Settings

TOKEN = "Tok3n-9f8e7d6c5b4a-secret"
PASSWORD = "hunter2-correct-horse"
REF = "${env:WELDCELL_TEST_TOKEN}"


@pytest.fixture(autouse=True)
def env(monkeypatch):
    monkeypatch.setenv("WELDCELL_TEST_TOKEN", TOKEN)
    monkeypatch.setenv("WELDCELL_TEST_PASSWORD", PASSWORD)
    yield
    secrets.forget_all()


class UrlSettings(Settings):
    url: str = Field(description="service URL")


def _probe(settings) -> str:
    if "down" in settings.url:
        raise DeviceError(f"no answer from {settings.url}", "check the service")
    return f"service answered at {settings.url}"


class LeakyJobSettings(Settings):
    label: str = Field("x", description="a free text copied everywhere")
    url: str = Field("", description="a URL the job says it cannot reach")


def _leaky_run(ctx) -> dict:
    """Puts its secret setting into every channel a job has, then fails like a dropped device."""
    s = ctx.settings
    logging.getLogger("weldcell.test").warning("connecting with %s to %s", s.label, s.url)
    with ctx.step("leak"):
        ctx.state.data["notes"]["label"] = s.label
        ctx.state.save()
        ctx.write_text("summary.txt", f"label {s.label}\nurl {s.url}\n")
        ctx.write_text("report/report.md", f"# report\n\n{s.label}\n")
        ctx.write_json("artefact.json", {"label": s.label, "url": s.url})
        robot = ctx.device("robot")
        robot.move_linear(robot.state().T_base_tcp)  # a dry-run log entry
        ctx.reporter.info(f"using {s.label}")
    raise DeviceError(f"service not reachable at {s.url} (label {s.label})", "call recover() to reconnect")


class Leaky:
    @hookimpl
    def weldcell_register_devices(self, register):
        register(DeviceSpec(name="service.url", kind="robot", summary="", settings=UrlSettings, probe=_probe))

    @hookimpl
    def weldcell_register_jobs(self, register):
        register(
            JobSpec(
                name="leaky-job",
                kind="job",
                summary="",
                settings=LeakyJobSettings,
                run=_leaky_run,
                devices=(
                    DeviceRole("robot", "robot", "the arm"),
                    DeviceRole("other", "robot", "a second service", optional=True),
                ),
            )
        )


def profile(tmp_path: Path, body: str) -> Path:
    f = tmp_path / "p.toml"
    f.write_text('schema = "weldcell/profile@1"\nname = "leaky"\n' + textwrap.dedent(body))
    return f


def no_secret(text: str) -> None:
    assert TOKEN not in text and PASSWORD not in text


@pytest.fixture
def leaky_pm(sim_pm):
    sim_pm.register(Leaky(), "leaky", distribution="weldcell-tests")
    return sim_pm


def test_redact_replaces_values_by_references_and_masks_url_credentials():
    secrets.register(TOKEN, REF)
    assert secrets.redact(f"a {TOKEN} b") == f"a {REF} b"
    assert secrets.redact("http://admin:pw1234@10.0.0.2/rw") == "http://admin:***@10.0.0.2/rw"
    assert secrets.redact("https://ghp_abcdef@host/x") == "https://***@host/x"
    assert secrets.redact("ws://h:1/v6.json?token=abc&x=1") == "ws://h:1/v6.json?token=***&x=1"
    assert secrets.redact("Authorization: Bearer abcdefgh12345") == "Authorization: Bearer ***"
    # references and ordinary text are left alone
    assert secrets.redact("http://${env:U}:${env:P}@h/") == "http://${env:U}:${env:P}@h/"
    assert secrets.redact("ws://127.0.0.1:6437/v6.json") == "ws://127.0.0.1:6437/v6.json"
    secrets.register("ab1", "${env:SHORT}")  # a short secret only as a whole word
    assert secrets.redact("ab1 tab12") == "${env:SHORT} tab12"


def test_devices_listing_prints_the_reference_not_the_token(leaky_pm, tmp_path, wide_console):
    p = profile(
        tmp_path,
        f"""
        [job]
        name = "leaky-job"
        [devices.robot]
        plugin = "service.url"
        settings = {{ url = "ws://127.0.0.1:6437/v6.json?token={REF}" }}
        [devices.other]
        plugin = "service.url"
        settings = {{ url = "http://admin:{PASSWORD}@127.0.0.1:9/down" }}
        """,
    )
    r = CliRunner().invoke(main, ["devices", str(p)])
    no_secret(r.output)
    assert f"service answered at ws://127.0.0.1:6437/v6.json?token={REF}" in r.output
    assert "no answer from http://admin:***@127.0.0.1:9/down" in r.output  # written in the file: masked
    assert r.exit_code == 5


def test_a_secret_in_a_wrongly_typed_key_is_named_by_its_reference(fixture_pm, tmp_path, wide_console):
    p = profile(
        tmp_path,
        f"""
        [job]
        name = "fixture-job"
        [job.settings]
        standoff = "{REF}"
        [devices.robot]
        plugin = "robot.sim"
        """,
    )
    for args in (["profiles", "validate", str(p)], ["run", str(p), "--runs-dir", str(tmp_path / "runs")]):
        r = CliRunner().invoke(main, args)
        no_secret(r.output)
        assert f"cannot read '{REF}' as a length" in r.output, r.output
        assert r.exit_code == 3


def test_a_failed_run_keeps_every_channel_free_of_the_secret(leaky_pm, tmp_path, wide_console, caplog):
    p = profile(
        tmp_path,
        f"""
        [job]
        name = "leaky-job"
        [job.settings]
        label = "{REF}"
        url = "https://operator:${{env:WELDCELL_TEST_PASSWORD}}@10.0.0.7:8443/api?token={REF}"
        [devices.robot]
        plugin = "robot.sim"
        [devices.robot.settings]
        model = "ur5"
        """,
    )
    caplog.set_level(logging.INFO)
    r = CliRunner().invoke(main, ["run", str(p), "--runs-dir", str(tmp_path / "runs"), "--dry-run"])
    assert r.exit_code == 5
    no_secret(r.output)
    assert f"(label {REF})" in r.output
    # a dropped device is answered with the command that resumes, not an API call
    assert "recover()" not in r.output and "--resume" in r.output
    (run_dir,) = list((tmp_path / "runs").iterdir())
    files = [f for f in run_dir.rglob("*") if f.is_file()]
    names = {f.name for f in files}
    assert {"state.json", "result.json", "summary.txt", "report.md", "artefact.json"} <= names
    for f in files:
        no_secret(f.read_text())
    result = read_json(run_dir / "result.json")
    settings = result["provenance"]["settings"]["job"]
    assert settings["label"] == REF
    assert settings["url"] == (
        f"https://operator:${{env:WELDCELL_TEST_PASSWORD}}@10.0.0.7:8443/api?token={REF}"
    )
    assert result["error"]["message"].endswith(f"(label {REF})")
    assert "--resume" in result["error"]["fix"] and "recover()" not in result["error"]["fix"]
    assert REF in result["provenance"]["secrets"]
    assert read_json(run_dir / "state.json")["notes"]["label"] == REF
    assert (run_dir / "summary.txt").read_text().startswith(f"label {REF}")
    logs = "\n".join(rec.getMessage() for rec in caplog.records)
    assert f"connecting with {REF}" in logs and "dry run: move_linear" in logs  # the robot's dry-run log
    no_secret(logs)


def test_a_sim_run_records_references_in_provenance_and_artefacts(fixture_pm, fixtures_dir, tmp_path):
    from weldcell.sdk.jobs import run_job

    p = tmp_path / "fixture.toml"
    p.write_text(
        (fixtures_dir / "fixture-job-sim.toml")
        .read_text()
        .replace('standoff = "15 mm"', f'standoff = "15 mm"\nlabel = "run by {REF}"')
    )
    run_dir, result = run_job(p, fixture_pm, runs_dir=tmp_path / "runs")
    assert result["status"] == "ok"
    assert result["provenance"]["settings"]["job"]["label"] == f"run by {REF}"
    assert read_json(run_dir / "scaled.json")["label"] == f"run by {REF}"
    for f in run_dir.rglob("*"):
        if f.is_file():
            no_secret(f.read_text())
