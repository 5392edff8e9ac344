"""camera.phoxi: GenTL mode against a faithful harvesters fake, file mode against real PhoXi PLY scans."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from peers_cell2_harvesters import FakeGenTLSystem, SimPhoXi
from weldcell.hal.lifecycle import State
from weldcell.plugins import phoxi as phoxi_plugin
from weldcell.plugins.phoxi.file_source import PhoXiFileCamera
from weldcell.plugins.phoxi.frames import exact_cloud, fit_intrinsics
from weldcell.plugins.phoxi.gentl import PhoXiGenTLCamera
from weldcell.plugins.phoxi.ply import read_ply_grid, write_ply_grid
from weldcell.plugins.phoxi.settings import PhoXiSettings
from weldcell.sdk.errors import DeviceError
from weldcell.testing.conformance import DepthCameraConformance

DATA = Path(__file__).resolve().parents[2] / ".." / "shared" / "data"
SAMPLE = DATA / "flange-handeye-ancorasir" / "calib_toolbox" / "data" / "2019-06-14-sample"
needs_sample = pytest.mark.skipif(not SAMPLE.is_dir(), reason=f"real PhoXi scans not found at {SAMPLE}")


@pytest.fixture
def gentl(tmp_path):
    cti = tmp_path / "photoneo.cti"
    cti.write_bytes(b"\x7fELF fake producer")
    return FakeGenTLSystem(
        cti=cti, scanners=[SimPhoXi(serial="TER-008"), SimPhoXi(serial="DVJ-104", width=40, height=30)]
    )


def _gentl_cam(system, **kw) -> PhoXiGenTLCamera:
    s = PhoXiSettings(cti_path=str(system.cti), device_id=kw.pop("device_id", "TER-008"), **kw)
    return PhoXiGenTLCamera(s, name="phoxi", harvester_factory=system.harvester)


class TestPhoXiGenTLConformance(DepthCameraConformance):
    @pytest.fixture
    def device(self, gentl):
        return _gentl_cam(gentl)

    @pytest.fixture
    def break_device(self, gentl):
        def _break(dev):
            gentl.scanners[0].unplugged = True

            def _replug():
                gentl.scanners[0].unplugged = False

            dev._replug = _replug  # noqa: SLF001 - test hook

        return _break

    def test_error_state_and_recovery(self, device, break_device, gentl):
        with device as d:
            d.capture()
            break_device(d)
            with pytest.raises(DeviceError, match="no scan"):
                d.capture()
            assert d.lifecycle is State.ERROR and "no scan" in d.health().message
            d._replug()
            d.recover()
            d.configure()
            d.activate()
            assert d.capture().depth.shape == (72, 96)
            assert gentl.acquirers[0].destroyed, "recover must release the old acquirer"


def test_gentl_frame_is_the_exact_point_map(gentl):
    sim = gentl.scanners[0]
    xyz_mm, normals, tex = sim.render()
    with _gentl_cam(gentl) as cam:
        f = cam.capture()
        k = cam.intrinsics()
    nm = gentl.acquirers[0].remote_device.node_map
    assert (nm.TriggerMode.value, nm.TriggerSource.value) == ("On", "Software")
    assert nm.enabled["Range"] and nm.enabled["Intensity"] and nm.enabled["Normal"]
    assert not nm.enabled["ColorCamera"]
    assert (k.fx, k.fy, k.cx, k.cy) == pytest.approx((sim.f, sim.f * sim.aspect, sim.cu, sim.cv))
    np.testing.assert_allclose(f.meta["xyz"], xyz_mm.astype(np.float64) * 1e-3, atol=1e-9)
    np.testing.assert_allclose(f.depth, xyz_mm[..., 2] * 1e-3, atol=1e-7)
    assert np.all(f.depth[:, :4] == 0), "unmeasured pixels must be depth 0"
    np.testing.assert_allclose(f.meta["normals"], normals, atol=1e-7)
    np.testing.assert_array_equal(f.meta["texture"], tex)
    exact = exact_cloud(f)
    back = f.to_cloud()
    assert len(exact) == len(back) == int((xyz_mm[..., 2] > 0).sum())
    # the scanner's published intrinsics are the pinhole the points were measured through
    np.testing.assert_allclose(back.points, exact.points, atol=1e-6)
    assert np.allclose(np.linalg.norm(exact.normals, axis=1), 1.0)


def test_gentl_selects_the_scanner_by_id_and_reports_choices(gentl, monkeypatch):
    with _gentl_cam(gentl, device_id="DVJ-104") as cam:
        assert cam.capture().depth.shape == (30, 40)
    cam = _gentl_cam(gentl, device_id="NOPE-1")
    with pytest.raises(DeviceError, match="TER-008"):
        cam.configure()
    cam = _gentl_cam(gentl, device_id="")
    with pytest.raises(DeviceError, match="2 scanners"):
        cam.configure()


def test_gentl_cti_lookup_from_the_environment(gentl, monkeypatch, tmp_path):
    monkeypatch.setenv("PHOXI_CTI", str(gentl.cti))
    s = PhoXiSettings(device_id="TER-008")
    with PhoXiGenTLCamera(s, harvester_factory=gentl.harvester) as cam:
        assert cam.capture().depth.max() > 0
    monkeypatch.delenv("PHOXI_CTI")
    monkeypatch.setenv("GENICAM_GENTL64_PATH", str(tmp_path / "empty"))
    with pytest.raises(DeviceError, match="GenTL producer") as e:
        PhoXiGenTLCamera(s, harvester_factory=gentl.harvester).configure()
    assert "cti_path" in e.value.fix
    monkeypatch.setenv("GENICAM_GENTL64_PATH", str(gentl.cti.parent))
    with PhoXiGenTLCamera(s, harvester_factory=gentl.harvester) as cam:
        assert cam.capture().depth.shape == (72, 96)


def test_gentl_without_normals_or_texture(gentl):
    with _gentl_cam(gentl, normals=False, texture=False) as cam:
        f = cam.capture()
    assert "normals" not in f.meta and f.color is None and f.depth.max() > 0


def test_probe(gentl, weldcell_pm):
    from weldcell.plugins.phoxi.gentl import probe_gentl

    s = PhoXiSettings(cti_path=str(gentl.cti), device_id="TER-008")
    assert "TER-008" in probe_gentl(s, gentl.harvester)
    gentl.scanners[0].unplugged = True
    with pytest.raises(DeviceError, match="not found"):
        probe_gentl(s, gentl.harvester)
    weldcell_pm.register(phoxi_plugin, "phoxi")
    spec = weldcell_pm.registry.get("device", "camera.phoxi")
    assert spec.kind == "depth_camera" and spec.settings is PhoXiSettings
    assert "PLY" in spec.probe(PhoXiSettings(mode="file", files=str(SAMPLE))) if SAMPLE.is_dir() else True


# ---------------------------------------------------------------------------------------------- file mode
@needs_sample
class TestPhoXiFileConformance(DepthCameraConformance):
    @pytest.fixture
    def device(self):
        return PhoXiFileCamera(PhoXiSettings(mode="file", files=str(SAMPLE / "*_tool.ply")), name="phoxi")


@needs_sample
def test_file_mode_replays_the_real_scans_exactly():
    files = sorted(SAMPLE.glob("*_tool.ply"))
    cam = PhoXiFileCamera(
        PhoXiSettings(mode="file", files=str(SAMPLE / "*_tool.ply"), loop=True), name="phoxi"
    )
    with cam:
        frames = [cam.capture() for _ in range(len(files) + 1)]
    assert [Path(f.meta["file"]).name for f in frames[:-1]] == [p.name for p in files]
    assert frames[-1].meta["file"] == frames[0].meta["file"], "loop starts again at the first file"
    for f, p in zip(frames, files, strict=False):
        raw = read_ply_grid(p).xyz * 1e-3
        assert not f.meta["organised"]  # the sample is a cropped (1 x N) export
        np.testing.assert_allclose(f.meta["points"], raw[raw[:, 2] > 0])
        z = f.depth[f.depth > 0]
        assert 0.6 < z.min() and z.max() < 0.8, "the flange sits ~0.72 m in front of the scanner"
        # every pixel keeps a real point, and back-projection lands within half a pixel of it
        exact = exact_cloud(f).points
        back = f.to_cloud().points
        k = f.intrinsics
        assert len(back) == len(exact) >= 0.5 * len(raw)
        assert np.max(np.abs(back[:, :2] - exact[:, :2])) <= 0.51 * exact[:, 2].max() / min(k.fx, k.fy)
        assert np.allclose(back[:, 2], exact[:, 2])


@needs_sample
def test_file_mode_stops_without_loop():
    cam = PhoXiFileCamera(PhoXiSettings(mode="file", files=str(SAMPLE / "01_tool.ply"), loop=False), name="p")
    with cam:
        cam.capture()
        with pytest.raises(DeviceError, match="replayed"):
            cam.capture()
        assert cam.lifecycle is State.ERROR


@pytest.mark.parametrize("binary", [True, False])
def test_organised_ply_keeps_its_grid_and_intrinsics(tmp_path, binary):
    sim = SimPhoXi(width=64, height=48)
    xyz_mm, normals, _ = sim.render()
    path = write_ply_grid(tmp_path / "scan.ply", xyz_mm, normals, binary=binary)
    ply = read_ply_grid(path)
    assert ply.organised and (ply.rows, ply.cols) == (48, 64)
    with PhoXiFileCamera(PhoXiSettings(mode="file", files=str(path)), name="phoxi") as cam:
        f = cam.capture()
        k = cam.intrinsics()
    assert f.depth.shape == (48, 64)
    assert (k.fx, k.fy, k.cx, k.cy) == pytest.approx((sim.f, sim.f * sim.aspect, sim.cu, sim.cv), rel=1e-4)
    assert f.meta["intrinsics_fit_rms_px"] < 1e-3
    np.testing.assert_allclose(f.meta["xyz"], xyz_mm * 1e-3, atol=1e-7)
    np.testing.assert_allclose(f.to_cloud().points, exact_cloud(f).points, atol=1e-5)


def test_units_and_bad_files(tmp_path):
    sim = SimPhoXi(width=32, height=24)
    xyz_mm, _, _ = sim.render()
    write_ply_grid(tmp_path / "m.ply", xyz_mm * 1e-3)
    with PhoXiFileCamera(PhoXiSettings(mode="file", files=str(tmp_path / "m.ply"), units="auto")) as cam:
        assert cam.capture().depth.max() < 1.0
    (tmp_path / "bad.ply").write_text("not a ply")
    with pytest.raises(DeviceError, match="not a PLY"):
        PhoXiFileCamera(PhoXiSettings(mode="file", files=str(tmp_path / "bad.ply"))).configure()
    with pytest.raises(DeviceError, match="no PLY file"):
        PhoXiFileCamera(PhoXiSettings(mode="file", files=str(tmp_path / "none*.ply"))).configure()


def test_fit_intrinsics_refuses_a_degenerate_map():
    from weldcell.sdk.errors import DataError

    with pytest.raises(DataError):
        fit_intrinsics(np.zeros((4, 4, 3)))
