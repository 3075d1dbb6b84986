"""The web viewer of a run (viser): the deformed mesh coloured by a chosen quantity with its
colour bar, the reference surface as a ghost, probes as labelled points on every frame,
obstacles under their scene names, a slider over the trajectory frames, a camera that frames
the mesh (on opening and with "fit to view") and the run's Π and Newton-decrement history as
an interactive plot (uPlot, viser's own; from result.json, so of a finished run).

The strain and energy fields are stored for the final state only (mesh.ply); earlier trajectory
frames can be coloured by displacement (from reference.obj) and are drawn plain otherwise.
Probes on an earlier frame are the solver's values where result.json records them per load
step, else interpolated on the frame's mesh (`RunFiles.probe_positions`; the note says so).
"""

from __future__ import annotations

import logging

import numpy as np

from taichi_ndf.extras import require
from taichi_ndf.io.run_files import QUANTITIES, RunFiles
from taichi_ndf.render.camera import frame_mesh, widest_azimuth
from taichi_ndf.render.figure import RANGE_PERCENTILES
from taichi_ndf.render.shaded import SURFACE_BGR, colormap, colour_bar, colour_range
from taichi_ndf.viewer.convergence import add_convergence_plot

__all__ = ["require_viewer", "RunViewer"]

log = logging.getLogger(__name__)

GHOST_RGB = (150, 150, 150)
OBSTACLE_RGB = (120, 120, 120)
PROBE_RGB = (220, 40, 40)
FOV_DEG = 40.0  # the viewer's vertical field of view (viser's default, 75, shows the mesh small)
OPENING_ASPECT = 4 / 3  # canvas width / height assumed before a browser reports its own


def require_viewer():
    """The viser module, or MissingExtra naming the [viewer] extra."""
    return require("viser", "viewer", "The web viewer")


class RunViewer:
    """A viser server showing one run; `url` is where a browser opens it.

    host: the interface to listen on (127.0.0.1: this machine only; reach a remote one with
    `ssh -L PORT:127.0.0.1:PORT`, or listen on 0.0.0.0); port: the TCP port asked for; `port`
    after construction: the one bound (the next free one when that was taken).
    """

    def __init__(self, run: RunFiles, *, host: str = "127.0.0.1", port: int = 8080,
                 frame: int | None = None):
        viser = require_viewer()
        if frame is not None and not -len(run.frames) <= frame < len(run.frames):
            raise ValueError(f"frame {frame} is not one of the run's {len(run.frames)} "
                             "trajectory frames")
        self.run = run
        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        self.port = self.server.get_port()  # viser takes the next free port if `port` is taken
        self.url = f"http://{host}:{self.port}"
        self.azimuth = widest_azimuth(run.deformed, run.faces, up=run.up)
        size = float(np.ptp(run.deformed, axis=0).max())
        scene, gui = self.server.scene, self.server.gui
        gui.main_panel.dock_right()  # the canvas beside the panel, not under it
        scene.set_up_direction(tuple(float(v) for v in run.up))
        camera = self.framing(run.deformed, OPENING_ASPECT)
        self.server.initial_camera.fov = np.radians(FOV_DEG)
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
            last = len(run.frames) - 1
            self.frame = gui.add_slider("frame", 0, last, 1,
                                        last if frame is None else frame % len(run.frames))
        self.ghost = gui.add_checkbox("reference (ghost)", run.reference is not None,
                                      disabled=run.reference is None)
        gui.add_button("fit to view").on_click(lambda event: self.fit(event.client))
        self.note = gui.add_markdown("")
        self.plot = self._history_plot(gui) if len(run.history[0]) > 1 else None
        self.colour_bar = gui.add_image(np.zeros((8, 8, 3), np.uint8), label="colour bar")

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
        self.probe_radius = 0.02 * size
        self.probes = []
        self.colour.on_update(lambda _: self.show())
        if self.frame is not None:
            self.frame.on_update(lambda _: self.show())
        self.show()

    def framing(self, vertices: np.ndarray, aspect: float):
        """The camera (`render.camera.Camera`) that frames `vertices` (V, 3) [m] from the
        three-quarter view that shows the final shape largest, in a canvas of this width /
        height at the viewer's field of view."""
        return frame_mesh(vertices, width=max(1, round(1000 * aspect)), height=1000,
                          up=tuple(self.run.up), azimuth_deg=self.azimuth, fov_y_deg=FOV_DEG)

    def fit(self, client) -> None:
        """Point `client`'s camera (a viser ClientHandle; None: every client) so that the
        shown frame fills its canvas."""
        clients = self.server.get_clients().values() if client is None else (client,)
        vertices = self.frame_state()[0]
        for c in clients:
            camera = self.framing(vertices, c.camera.aspect)
            with c.atomic():
                c.camera.fov = np.radians(FOV_DEG)
                c.camera.up_direction = tuple(float(v) for v in self.run.up)
                c.camera.position = tuple(camera.eye)
                c.camera.look_at = tuple(camera.target)

    def _history_plot(self, gui):
        """The run's convergence plot (`viewer.convergence`): Π and, for projected Newton, the
        Newton decrement per iteration."""
        iterations, energies = self.run.history
        decrements = self.run.decrements if len(self.run.decrements) == len(iterations) else None
        return add_convergence_plot(gui, iterations, energies, decrements)

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
        index = None if self.frame is None else int(self.frame.value)
        try:
            positions, exact = self.run.probe_positions(index)
        except ValueError:  # an old run without reference.obj: final positions only
            positions, exact = None, True
            note += "; probes are known at the final frame only"
        if not exact:
            note += "; probes interpolated on the frame's mesh"
        self.note.content = note
        self._draw_probes(positions)

    def _draw_probes(self, positions: np.ndarray | None) -> None:
        """Each probe as a red sphere with its name at `positions` (P, 3) [m]; None hides
        them."""
        scene = self.server.scene
        if positions is None:
            for handles in self.probes:
                for handle in handles:
                    handle.visible = False
            return
        if not self.probes:
            for probe, position in zip(self.run.probes, positions, strict=True):
                self.probes.append((
                    scene.add_icosphere(f"/probes/{probe.name}", radius=self.probe_radius,
                                        color=PROBE_RGB, position=tuple(position)),
                    scene.add_label(f"/probe_labels/{probe.name}", probe.name,
                                    position=tuple(position), anchor="bottom-left")))
            return
        for handles, position in zip(self.probes, positions, strict=True):
            for handle in handles:
                handle.position = tuple(float(v) for v in position)
                handle.visible = True

    def stop(self) -> None:
        self.server.stop()
