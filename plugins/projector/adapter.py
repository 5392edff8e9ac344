"""The window projector: pygame shows the projector's image fullscreen on a chosen display output.

weldcell's OpenCV is the headless build (no windows), so OpenCV only draws (anti-aliased lines into a
numpy image, :mod:`.render`) and pygame/SDL opens the borderless fullscreen window on the projector's
display and blits the image. Segments come in the world frame; the projector's pose is its mount
(``T_world_projector()``), evaluated at project time so a flange-mounted projector follows the robot.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable

import numpy as np

os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
import pygame  # noqa: E402
from weldcell.hal.interfaces import LaserProjector  # noqa: E402
from weldcell.hal.readings import Intrinsics  # noqa: E402
from weldcell.plugins.projector import render  # noqa: E402
from weldcell.plugins.projector.settings import WindowProjectorSettings  # noqa: E402
from weldcell.sdk.errors import DeviceError  # noqa: E402

log = logging.getLogger("weldcell.projector")


class WindowProjector(LaserProjector):
    """A video laser projector as a fullscreen window (device ``projector.window``)."""

    def __init__(
        self,
        settings: WindowProjectorSettings | None = None,
        name: str = "projector",
        T_world_projector: Callable[[], np.ndarray] | None = None,
    ) -> None:
        super().__init__(name, frame="world")
        self.settings = s = settings or WindowProjectorSettings()
        self.intrinsics = Intrinsics(
            s.width,
            s.height,
            s.fx,
            s.fy,
            s.width / 2 if s.cx is None else s.cx,
            s.height / 2 if s.cy is None else s.cy,
            tuple(s.dist),
        )
        self._pose = T_world_projector or (lambda: np.eye(4))
        self._screen = None
        self.image = np.zeros((s.height, s.width, 3), np.uint8)
        """The image shown now (H, W, 3) RGB."""

    def T_world_projector(self) -> np.ndarray:
        """The projector's pose in the world now (optical frame: z out of the lens, x right, y down)."""
        return np.asarray(self._pose(), dtype=float)

    # -- lifecycle -------------------------------------------------------------------------------
    def on_configure(self) -> None:
        s = self.settings
        try:
            pygame.display.init()
        except pygame.error as e:
            raise DeviceError(
                f"no display for the projector window: {e}",
                "run on the desktop the projector is connected to (DISPLAY / a Wayland session), "
                "with the projector connected as an extra display",
            ) from e
        n = pygame.display.get_num_displays()
        if s.display >= n:
            sizes = ", ".join(f"{i}: {w}x{h}" for i, (w, h) in enumerate(pygame.display.get_desktop_sizes()))
            pygame.display.quit()
            raise DeviceError(
                f"display {s.display} does not exist ({n} connected: {sizes})",
                "connect the projector and set display to its index",
            )
        size = pygame.display.get_desktop_sizes()[s.display]
        if tuple(size) != (s.width, s.height):
            log.warning(
                "display %d is %dx%d but the projector is %dx%d: set the output's mode to the projector's "
                "native resolution, or the image is scaled",
                s.display,
                *size,
                s.width,
                s.height,
            )
        flags = (pygame.FULLSCREEN | pygame.NOFRAME) if s.fullscreen else 0
        try:
            self._screen = pygame.display.set_mode((s.width, s.height), flags, display=s.display)
        except pygame.error as e:
            pygame.display.quit()
            raise DeviceError(f"cannot open the projector window: {e}", "check the display output") from e
        pygame.display.set_caption(f"weldcell projector {self.name}")
        pygame.mouse.set_visible(False)
        self._show(np.zeros_like(self.image))

    def on_deactivate(self) -> None:
        if self._screen is not None:
            self._show(np.zeros_like(self.image))  # dark when not in use

    def on_close(self) -> None:
        self._screen = None
        try:
            pygame.display.quit()
        except pygame.error as e:  # noqa: PERF203 - a lost display must not stop closing
            log.debug("display quit: %s", e)

    # -- drawing ---------------------------------------------------------------------------------
    def _show(self, img: np.ndarray) -> None:
        if self._screen is None or not pygame.display.get_init() or pygame.display.get_surface() is None:
            raise self.fault("the projector window is gone (display closed or disconnected)")
        try:
            pygame.event.pump()
            surf = pygame.image.frombuffer(
                np.ascontiguousarray(img).tobytes(), (img.shape[1], img.shape[0]), "RGB"
            )
            self._screen.blit(surf, (0, 0))
            pygame.display.flip()
        except pygame.error as e:
            raise self.fault(f"drawing on the projector window failed: {e}") from e
        self.image = img

    def render(self, segments: np.ndarray) -> np.ndarray:
        """The image (H, W, 3) that shows world segments (N, 2, 3) from the projector's current pose."""
        s = self.settings
        lines = render.project_segments(segments, self.T_world_projector(), self.intrinsics, s.near)
        return render.draw(lines, self.intrinsics, s.color, s.line_width)

    def _project(self, segments: np.ndarray, label: str) -> None:
        self._show(self.render(segments))

    def _clear(self) -> None:
        self._show(np.zeros_like(self.image))
