"""``arcsem-view RUN``: the trained model in the browser, rendered by arcsem's own CPU rasteriser.

A viser server (its web client ships inside the wheel and works offline) shows, per connected
browser, the frames :class:`~.session.Session` renders: previews at an adaptive resolution while the
camera moves, the full resolution once it rests. GUI: display mode (grey: the stage-1 model with
the mean ACT; colour: the stage-2 model where the run has one; depth: turbo map of the surface
depth over the frame's range, near red; normal: camera-space normals), camera model (pinhole |
orthographic), and the training cameras as frusta (drawn at most 2 scene sizes from the centre, on
their true lines of sight).
"""
from __future__ import annotations

import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .camera import ViewState, frustum_poses, rotmat_to_wxyz, state_cameras
from .session import AdaptiveResolution, Session

__all__ = ["MODES", "Viewer", "ViewerConfig", "render_mode"]

MODES = ("grey", "colour", "depth", "normal")


@dataclass
class ViewerConfig:
    host: str = "127.0.0.1"
    port: int = 8080
    max_height: int = 1024  # resting frames at the canvas height, at most this
    target_s: float = 0.15  # preview frame time the adaptive resolution aims at
    frusta: bool = True


def render_mode(models: dict[str, Any], state: ViewState, height: int, mode: str, camera: str) -> np.ndarray:
    """uint8 ``[H, W, 3]`` of ``mode`` for the browser camera ``state`` (``models``: grey, colour)."""
    from ..visual import depth_rgb, normal_rgb, render_layers, to_uint8

    cams = state_cameras(state, height, camera)
    model = models["colour"] if mode == "colour" and models.get("colour") is not None else models["grey"]
    lay = render_layers(model, cams, normals=mode == "normal")
    if mode == "depth":
        return depth_rgb(lay["depth"][0], lay["valid"][0])
    if mode == "normal":
        return normal_rgb(lay["normal"][0], cams, lay["valid"][0])
    return to_uint8(lay["rgb"][0])


class Viewer:
    """The server: ``Viewer(run_dir).start()``; :attr:`sessions` holds one :class:`Session` per client."""

    def __init__(self, run_dir: str | Path, cfg: ViewerConfig | None = None):
        from ..orbit import orbit_frame
        from ..runs import has_colour, load_run

        self.cfg = cfg or ViewerConfig()
        grey = load_run(run_dir, colored=False)
        colour = load_run(run_dir, colored=True).backbone if has_colour(run_dir) else None
        self.models = {"grey": grey.backbone, "colour": colour}
        self.scene = grey.scene
        self.frame = orbit_frame(self.scene.train.cameras, self.scene.bounds)
        self.sessions: dict[int, Session] = {}
        self.server = None
        self._lock = threading.Lock()  # one render at a time: the rasteriser uses every core

    def start(self) -> Viewer:
        import viser

        self.server = viser.ViserServer(host=self.cfg.host, port=self.cfg.port, verbose=False)
        s = self.server
        s.scene.set_up_direction(tuple(self.frame.up.tolist()))
        s.gui.add_markdown("**arcsem** — rendered on the CPU by arcsem; previews while moving, full "
                           "resolution at rest. Frusta: training cameras (on their lines of sight).")
        modes = [m for m in MODES if m != "colour" or self.models["colour"] is not None]
        self.mode = s.gui.add_dropdown("display", modes, initial_value="colour" if "colour" in modes else "grey")
        self.camera = s.gui.add_dropdown("camera", ["pinhole", "orthographic"],
                                         initial_value=self.scene.train.cameras.model)
        for handle in (self.mode, self.camera):
            handle.on_update(lambda _: [sess.changed() for sess in self.sessions.values()])
        if self.cfg.frusta:
            self._frusta()
        s.on_client_connect(self._connect)
        s.on_client_disconnect(lambda c: self.sessions.pop(c.client_id).stop() if c.client_id in self.sessions else None)
        return self

    def _frusta(self) -> None:
        cams = self.scene.train.cameras
        centre = self.frame.centre.numpy()
        for i, (wxyz, pos, fov, aspect) in enumerate(frustum_poses(cams, centre, self.frame.size, far=2.0)):
            self.server.scene.add_camera_frustum(f"/train/{self.scene.train.names[i]}", fov=fov, aspect=aspect,
                                                 scale=0.05 * self.frame.size, wxyz=wxyz, position=pos,
                                                 color=(40, 90, 200))

    def initial_view(self) -> tuple[np.ndarray, np.ndarray, float]:
        """``(wxyz, position, fov)``: in front of the specimen (30 degrees right and up, off the lines of
        sight of the usual SEM arcs), farther than the frusta, framing the specimen."""
        import math

        import torch

        from ..orbit import view_cameras

        dist = 3.5 * self.frame.size
        cam = view_cameras(self.frame, torch.tensor([30.0]), torch.tensor([30.0]), self.scene.train.cameras[0],
                           64, 64, "pinhole", radius=dist)
        c2w = cam.cam_to_world[0].double().numpy()
        return rotmat_to_wxyz(c2w[:3, :3]), c2w[:3, 3], 2 * math.atan(0.5 * self.frame.size / dist) * 1.3

    def _connect(self, client) -> None:
        wxyz, pos, fov = self.initial_view()
        with client.atomic():
            client.camera.fov = fov
            client.camera.look_at = tuple(self.frame.centre.tolist())
            client.camera.up_direction = tuple(self.frame.up.tolist())
            client.camera.wxyz = tuple(wxyz.tolist())
            client.camera.position = tuple(pos.tolist())

        def state() -> tuple:
            c = client.camera
            return (ViewState(tuple(c.wxyz), tuple(c.position), tuple(c.look_at), float(c.fov), float(c.aspect)),
                    str(self.mode.value), str(self.camera.value))

        def render(st: tuple, height: int) -> np.ndarray:
            with self._lock:
                return render_mode(self.models, st[0], height, st[1], st[2])

        def show(image: np.ndarray) -> None:
            client.scene.set_background_image(image, format="jpeg", jpeg_quality=90)

        policy = AdaptiveResolution(target_s=self.cfg.target_s, max_height=self.cfg.max_height)
        sess = Session(state, render, show, lambda: int(client.camera.image_height or 480), policy)
        self.sessions[client.client_id] = sess
        client.camera.on_update(lambda _: sess.changed())
        sess.start().changed()

    def stop(self) -> None:
        for sess in list(self.sessions.values()):
            sess.stop()
        if self.server is not None:
            self.server.stop()
