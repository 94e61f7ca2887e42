"""A scene's placement elements uploaded for drawing, and the draw calls of any subset of them.

Every scene object is one upload (:class:`~farfield.core.render.raster.MeshRenderer`): a whole
object as it is, a split object (:class:`~farfield.core.placement.hierarchy.Elements`: clusters
``name#k``) as its clusters' faces one after another in element order, in its one index buffer.
:meth:`ElementDraws.draws` gives one draw call per whole object and one per run of consecutive
clusters of a split object (its index range; the whole upload when every cluster is drawn), in
element order.  So an object drawn whole costs one draw call, as the planner counts it
(``Elements.draw_calls``: each cluster ``1 / n`` of its object's call), and any cluster can still
be left out on its own (an impostor replaces it, the PVS or the frustum culls it).  The placement
runtime (:mod:`farfield.core.placement.runtime`) and the calibration on a scene's own views
(:mod:`farfield.core.placement.calibration`) draw through it.
"""

from __future__ import annotations

import time
from typing import Self

import numpy as np

from farfield.core.placement.hierarchy import Elements
from farfield.core.render.raster import Camera, MeshRenderer
from farfield.core.scene import Scene


class IndexRange:
    """A run of an uploaded object's index buffer, drawn by ``render`` as the whole VAO would be."""

    __slots__ = ("vao", "first", "vertices")

    def __init__(self, vao, first: int, vertices: int):
        self.vao, self.first, self.vertices = vao, first, vertices

    def render(self, mode) -> None:
        self.vao.render(mode, vertices=self.vertices, first=self.first)  # ``first`` counts indices


class ElementDraws:
    """``scene``'s ``elements`` uploaded once (see the module docstring); release with
    :meth:`release` or use as a context manager."""

    def __init__(self, scene: Scene, elements: Elements):
        self.elements = elements
        E = elements
        # slots[i] = (upload, first face, faces) of element i; faces None: the whole object.
        objects, self._slots = [], []
        for i in range(E.count):
            piece = E.faces[i]
            if piece is None:
                self._slots.append((len(objects), 0, None))
                objects.append(scene.objects[int(E.object_index[i])])
            elif i == 0 or E.object_index[i - 1] != E.object_index[i] or E.faces[i - 1] is None:
                obj = scene.objects[int(E.object_index[i])]
                end = i
                while end < E.count and E.object_index[end] == E.object_index[i] and E.faces[end] is not None:
                    end += 1
                pieces = [E.faces[j] for j in range(i, end)]
                starts = np.concatenate([[0], np.cumsum([p.size for p in pieces])])
                self._slots.extend((len(objects), int(starts[k]), int(pieces[k].size)) for k in range(len(pieces)))
                objects.append(obj.with_faces(np.concatenate(pieces), obj.name))
        self.renderer = MeshRenderer(objects)
        self._uploads = list(self.renderer._draws)
        self._runs: dict[tuple[int, int, int], tuple] = {}  # (upload, first face, faces) -> its draw

    def draws(self, elements) -> list[tuple]:
        """The draws of ``elements`` (indices, ascending), in element order."""
        draws, run = [], None  # run: [upload, first face, faces, last element]
        for i in elements:
            i = int(i)
            upload, first, faces = self._slots[i]
            if faces is not None and run is not None and run[0] == upload and run[3] == i - 1:
                run[2] += faces
                run[3] = i
                continue
            if run is not None:  # closed before the next draw of any kind: element order kept
                draws.append(self._run_draw(*run[:3]))
                run = None
            if faces is None:
                draws.append(self._uploads[upload])
            else:
                run = [upload, first, faces, i]
        if run is not None:
            draws.append(self._run_draw(*run[:3]))
        return draws

    def _run_draw(self, upload: int, first: int, faces: int) -> tuple:
        whole = self._uploads[upload]
        if first == 0 and faces == whole[0].faces.shape[0]:
            return whole
        key = (upload, first, faces)
        draw = self._runs.get(key)
        if draw is None:
            draw = (*whole[:3], IndexRange(whole[3], 3 * first, 3 * faces), *whole[4:])
            self._runs[key] = draw
        return draw

    def frame_seconds(self, camera: Camera, draws: list[tuple]) -> float:
        """Seconds to draw ``draws`` (from :meth:`draws`) and finish (no read-back)."""
        gpu = self.renderer
        saved, gpu._draws = gpu._draws, list(draws)
        try:
            gpu.ctx.finish()
            start = time.perf_counter()
            gpu._draw(camera)
            gpu.ctx.finish()
            return time.perf_counter() - start
        finally:
            gpu._draws = saved

    def release(self) -> None:
        self.renderer.release()
        self._runs.clear()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc) -> None:
        self.release()
