"""Hook specifications: everything a weldcell plugin can provide.

A plugin is a module (or object) with functions named like the hooks below, decorated with
:data:`hookimpl`, exposed through the ``weldcell`` entry-point group::

    # pyproject.toml of your distribution
    [project.entry-points.weldcell]
    my_seams = "my_package.weldcell_plugin"

Each ``weldcell_register_*`` hook is called once, when the plugin manager collects the registry,
with a ``register`` callback. Call ``register(descriptor)`` for each thing you provide; the
descriptor types are in :mod:`weldcell.sdk.descriptors`. Register cheaply: do not import vendor
libraries or open devices here (declare them in ``requires`` and import inside the factory).
First-party plugins use exactly the same hooks and entry points.
"""

from __future__ import annotations

from collections.abc import Callable

import pluggy
from weldcell.sdk.descriptors import CommandSpec, DeviceSpec, ExporterSpec, JobSpec, StageSpec

PROJECT = "weldcell"
hookspec = pluggy.HookspecMarker(PROJECT)
hookimpl = pluggy.HookimplMarker(PROJECT)


@hookspec
def weldcell_register_stages(register: Callable[[StageSpec], None]) -> None:
    """Register methods (stages): seam detectors, registrations, filters, path planners, solvers.

    :param register: call with a :class:`~weldcell.sdk.descriptors.StageSpec` for each stage.

    Called once per collection. The stage's ``kind`` fixes its call signature
    (see :mod:`weldcell.sdk.stages`).

    Example::

        @hookimpl
        def weldcell_register_stages(register):
            register(StageSpec(name="seam.my-detector", kind="seam", summary="...",
                               settings=MySettings, factory=MyDetector))
    """


@hookspec
def weldcell_register_devices(register: Callable[[DeviceSpec], None]) -> None:
    """Register device adapters (real or simulated) for the HAL device kinds.

    :param register: call with a :class:`~weldcell.sdk.descriptors.DeviceSpec` for each adapter.

    Called once per collection. ``factory(settings, context)`` is called when a job opens the
    device; the returned object must subclass the HAL interface of the device's kind.

    Example::

        @hookimpl
        def weldcell_register_devices(register):
            register(DeviceSpec(name="robot.my-arm", kind="robot", summary="My arm over TCP",
                                settings=MyArmSettings, factory=make_my_arm,
                                requires={"my_arm_sdk": "my-arm"}))
    """


@hookspec
def weldcell_register_jobs(register: Callable[[JobSpec], None]) -> None:
    """Register jobs (``scan-and-plan``, ``calibrate``, ...) that ``weldcell run`` can execute.

    :param register: call with a :class:`~weldcell.sdk.descriptors.JobSpec` for each job.

    Example::

        @hookimpl
        def weldcell_register_jobs(register):
            register(JobSpec(name="inspect", kind="job", summary="...", run=run_inspect,
                             devices=(DeviceRole("camera", "depth_camera", "..."),)))
    """


@hookspec
def weldcell_register_exporters(register: Callable[[ExporterSpec], None]) -> None:
    """Register exporters that turn a ``weldcell/weld-path@1`` result into a robot program or table.

    :param register: call with an :class:`~weldcell.sdk.descriptors.ExporterSpec` for each exporter.

    Example::

        @hookimpl
        def weldcell_register_exporters(register):
            register(ExporterSpec(name="export.kuka-krl", kind="exporter", summary="KUKA KRL .src",
                                  export=to_krl, suffix=".src"))
    """


@hookspec
def weldcell_register_commands(register: Callable[[CommandSpec], None]) -> None:
    """Add sub-commands to the ``weldcell`` command line.

    :param register: call with a :class:`~weldcell.sdk.descriptors.CommandSpec` holding a
        ``click.Command``.

    Called when the CLI starts. Command names must not clash with built-in ones.

    Example::

        @hookimpl
        def weldcell_register_commands(register):
            register(CommandSpec(name="seam", command=seam_command, summary="seams of a cloud"))
    """


@hookspec
def weldcell_check_profile(profile) -> list[tuple[tuple[str, ...], str]] | None:
    """Check the parts of a profile this plugin owns, beyond what settings models check.

    :param profile: the :class:`~weldcell.sdk.profile.LoadedProfile` being validated.
    :return: a list of ``(key path, "what is wrong; what to do")`` problems, or None.

    Called by ``weldcell profiles validate`` and before every run, before any device opens.
    The simulated cell uses it to check the ``[sim]`` scene (workpiece kinds and sizes).

    Example::

        @hookimpl
        def weldcell_check_profile(profile):
            if profile.profile.job.name == "inspect" and "camera" not in profile.profile.devices:
                return [(("devices",), "inspect needs a camera; add [devices.camera]")]
    """


HOOKS = (
    weldcell_register_stages,
    weldcell_register_devices,
    weldcell_register_jobs,
    weldcell_register_exporters,
    weldcell_register_commands,
    weldcell_check_profile,
)
"""Every hook, in the order the plugin manager collects them."""
