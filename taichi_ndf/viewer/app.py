"""The web viewer of a run (viser): the deformed mesh coloured by a chosen quantity with its
colour bar, the reference surface as a ghost, probes as labelled points, obstacles, a slider
over the trajectory frames and the run's Π history.

The strain and energy fields are stored for the final state only (mesh.ply); earlier trajectory
frames can be coloured by displacement (from reference.obj) and are drawn plain otherwise.
"""

from __future__ import annotations

import logging

import numpy as np

from taichi_ndf.extras import require
from taichi_ndf.io.run_files import QUANTITIES, RunFiles
from taichi_ndf.render import plot_curves
from taichi_ndf.render.camera import frame_mesh, widest_azimuth
from taichi_ndf.render.figure import RANGE_PERCENTILES
from taichi_ndf.render.shaded import SURFACE_BGR, colormap, colour_bar, colour_range

__all__ = ["require_viewer", "RunViewer"]

log = logging.getLogger(__name__)

GHOST_RGB = (150, 150, 150)
OBSTACLE_RGB = (120, 120, 120)
PROBE_RGB = (220, 40, 40)


def require_viewer():
    """The viser module, or MissingExtra naming the [viewer] extra."""
    return require("viser", "viewer", "The web viewer")


class RunViewer:
    """A viser server showing one run; `url` is where a browser opens it.

    host: the interface to listen on (127.0.0.1: this machine only; reach a remote one with
    `ssh -L PORT:127.0.0.1:PORT`, or listen on 0.0.0.0); port: the TCP port asked for; `port`
    after construction: the one bound (the next free one when that was taken).
    """

    def __init__(self, run: RunFiles, *, host: str = "127.0.0.1", port: int = 8080):
        viser = require_viewer()
        self.run = run
        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        self.port = self.server.get_port()  # viser takes the next free port if `port` is taken
        self.url = f"http://{host}:{self.port}"
        size = float(np.ptp(run.deformed, axis=0).max())
        scene, gui = self.server.scene, self.server.gui
        scene.set_up_direction(tuple(float(v) for v in run.up))
        camera = frame_mesh(run.deformed, width=4, height=3, up=tuple(run.up),
                            azimuth_deg=widest_azimuth(run.deformed, run.faces, up=run.up))
        self.server.initial_camera.position = tuple(camera.eye)
        self.server.initial_camera.look_at = tuple(camera.target)
        self.server.initial_camera.up = tuple(float(v) for v in run.up)

        gui.add_markdown(f"**{run.name}** — `{run.path}`")
        choices = run.available()
        self.colour = gui.add_dropdown("colour", tuple(choices + ["none"]),
                                       initial_value="bending_strain"
                                       if "bending_strain" in choices else "none")
        self.frame = None
        if run.frames:
            self.frame = gui.add_slider("frame", 0, len(run.frames) - 1, 1, len(run.frames) - 1)
        self.ghost = gui.add_checkbox("reference (ghost)", run.reference is not None,
                                      disabled=run.reference is None)
        self.colour_bar = gui.add_image(np.zeros((8, 8, 3), np.uint8), label="colour bar")
        self.note = gui.add_markdown("")
        if len(run.history[0]) > 1:
            plot = plot_curves({"Pi": run.history}, title="Total potential energy",
                               xlabel="iteration", ylabel="Pi [J]", width=480, height=300)
            gui.add_image(plot[:, :, ::-1], label="Pi history")

        if run.reference is not None:
            self._reference = scene.add_mesh_simple(
                "/reference", run.reference, run.faces, color=GHOST_RGB, opacity=0.25,
                side="double", cast_shadow=False)
            self.ghost.on_update(lambda _: setattr(self._reference, "visible",
                                                   self.ghost.value))
        names = run.obstacle_names or tuple(str(k) for k in range(len(run.obstacles)))
        for name, obstacle in zip(names, run.obstacles, strict=True):
            scene.add_mesh_simple(f"/obstacles/{name}", obstacle.vertices, obstacle.faces,
                                  color=OBSTACLE_RGB, side="double")
        self.probes = [handle for probe in run.probes for handle in (
            scene.add_icosphere(f"/probes/{probe.name}", radius=0.02 * size, color=PROBE_RGB,
                                position=tuple(probe.deformed)),
            scene.add_label(f"/probe_labels/{probe.name}", probe.name,
                            position=tuple(probe.deformed), anchor="bottom-left"))]
        self.colour.on_update(lambda _: self.show())
        if self.frame is not None:
            self.frame.on_update(lambda _: self.show())
        self.show()

    def frame_state(self) -> tuple[np.ndarray, np.ndarray | None, str]:
        """Positions (V, 3) of the selected frame, its values of the chosen quantity (or None)
        and a note on what is shown."""
        quantity = self.colour.value
        index = None if self.frame is None else int(self.frame.value)
        final = index is None or index == len(self.run.frames) - 1
        vertices = self.run.deformed if index is None else self.run.frames[index].vertices
        note = "" if index is None else (f"frame {index} of {len(self.run.frames)}, load factor "
                                         f"{self.run.frames[index].load_factor:.4g}")
        if quantity == "none":
            return vertices, None, note
        if final or quantity == "displacement":
            if quantity == "displacement":
                return vertices, np.linalg.norm(vertices - self.run.reference, axis=1), note
            return vertices, self.run.quantity(quantity), note
        return vertices, None, note + f"; {quantity} is stored for the final frame only"

    def show(self) -> None:
        """Draw the deformed mesh of the selected frame in the selected colour."""
        import trimesh

        vertices, values, note = self.frame_state()
        if values is None:
            rgb = np.broadcast_to(SURFACE_BGR[::-1], (len(vertices), 3))
            bar = np.zeros((8, 8, 3), np.uint8)
        else:
            value_range = colour_range(values, RANGE_PERCENTILES)
            rgb = colormap(values, value_range)[:, ::-1]
            bar = colour_bar(value_range, QUANTITIES[self.colour.value], 320)[:, :, ::-1]
        # glTF vertex colours are linear; three.js encodes the lit result to sRGB.
        linear = 255.0 * ((np.asarray(rgb) / 255.0 + 0.055) / 1.055) ** 2.4
        colours = np.concatenate([np.rint(linear), np.full((len(rgb), 1), 255.0)], axis=1)
        mesh = trimesh.Trimesh(vertices, self.run.faces, vertex_colors=colours.astype(np.uint8),
                               process=False)
        self.server.scene.add_mesh_trimesh("/deformed", mesh)
        self.colour_bar.image = np.ascontiguousarray(bar)
        self.colour_bar.visible = values is not None
        self.note.content = note
        final = self.frame is None or int(self.frame.value) == len(self.run.frames) - 1
        for handle in self.probes:  # probes.json holds their final positions only
            handle.visible = final

    def stop(self) -> None:
        self.server.stop()
