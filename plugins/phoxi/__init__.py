"""Photoneo PhoXi 3D scanner (``camera.phoxi``): GenTL through harvesters, or PLY replay."""

from __future__ import annotations

from weldcell.sdk.descriptors import DeviceSpec
from weldcell.sdk.hookspecs import hookimpl


def _gentl_module():
    try:
        from . import gentl
    except ModuleNotFoundError as e:
        if e.name and e.name.split(".")[0] in ("harvesters", "genicam"):
            from weldcell.sdk.errors import MissingExtraError

            raise MissingExtraError("device 'camera.phoxi' (mode 'device')", e.name, "phoxi") from e
        raise
    return gentl


def _factory(settings, ctx):
    name = getattr(ctx, "role", "phoxi") if ctx is not None else "phoxi"
    if settings.mode == "file":
        from .file_source import PhoXiFileCamera

        return PhoXiFileCamera(settings, name=name)
    return _gentl_module().PhoXiGenTLCamera(settings, name=name)


def _probe(settings) -> str:
    if settings.mode == "file":
        from .file_source import resolve_files

        files = resolve_files(settings.files)
        return f"PhoXi file replay: {len(files)} PLY file(s), first {files[0].name}"
    return _gentl_module().probe_gentl(settings)


@hookimpl
def weldcell_register_devices(register):
    from .settings import PhoXiSettings

    register(
        DeviceSpec(
            name="camera.phoxi",
            kind="depth_camera",
            summary="Photoneo PhoXi 3D scanner (GenTL via harvesters, or PLY replay)",
            settings=PhoXiSettings,
            factory=_factory,
            probe=_probe,
        )
    )
