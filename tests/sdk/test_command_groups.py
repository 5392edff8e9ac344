"""Plugins that add sub-commands to one shared group (``weldcell map relocalize``, ``weldcell map serve``)."""

from __future__ import annotations

import click
from click.testing import CliRunner
from weldcell.sdk.cli import main
from weldcell.sdk.descriptors import CommandSpec
from weldcell.sdk.hookspecs import hookimpl


def _plugin(name: str, text: str):
    @click.command()
    def cmd():
        click.echo(text)

    class Plugin:
        @hookimpl
        def weldcell_register_commands(self, register):
            register(CommandSpec(name=f"site {name}", command=cmd, summary=text))

    return Plugin()


def test_two_plugins_share_one_group(weldcell_pm, register_plugin):
    runner = CliRunner()
    survey, ship = _plugin("survey", "surveying"), _plugin("ship", "shipping")
    with register_plugin(survey, "one"), register_plugin(ship, "two"):
        top = runner.invoke(main, ["--help"], catch_exceptions=False)
        assert "site" in top.output
        listing = runner.invoke(main, ["site", "--help"], catch_exceptions=False)
        assert "survey" in listing.output and "ship" in listing.output
        r = runner.invoke(main, ["site", "ship"], catch_exceptions=False)
        assert r.exit_code == 0 and "shipping" in r.output
        r = runner.invoke(main, ["site", "survey"], catch_exceptions=False)
        assert r.exit_code == 0 and "surveying" in r.output
    assert runner.invoke(main, ["site", "ship"]).exit_code == 2  # gone with the plugins


def test_a_group_a_plugin_registers_whole_gains_the_members(weldcell_pm, register_plugin):
    @click.group("site")
    def site():
        """The site group of one plugin."""

    @site.command("own")
    def own():
        click.echo("own member")

    class Whole:
        @hookimpl
        def weldcell_register_commands(self, register):
            register(CommandSpec(name="site", command=site, summary="site tools"))

    runner = CliRunner()
    with register_plugin(Whole(), "whole"), register_plugin(_plugin("ship", "shipping"), "two"):
        assert "shipping" in runner.invoke(main, ["site", "ship"], catch_exceptions=False).output
        assert "own member" in runner.invoke(main, ["site", "own"], catch_exceptions=False).output
