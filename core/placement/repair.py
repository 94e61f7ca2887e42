"""The planner's state, kept for check-and-repair rounds after the impostors are baked.

The thesis builds each impostor inside its greedy loop and measures it before the next choice
(seed 000 §5.7.3).  farfield bakes the chosen impostors afterwards, in parallel on render workers,
so the greedy's figures are estimates (the cost model over the technique's cheap layer estimate,
§5.8.1).  The check-and-repair round is the distributed form of §5.7.3: once a round's impostors
are baked, :meth:`PlannerState.repair` puts each one's real figures in place of the estimates
(its quads, hence its drawing time in every CPV it is drawn in, and its texture bytes, hence its
memory), every candidate not baked is scaled by the median ratio of baked to estimated figures
(the estimates' bias on this scene), and the CPVs that the real figures push over ``t_max`` go back
to the greedy, which resumes with every candidate not yet chosen (§5.7.4: scores only fall, so the
lazy heap starts from fresh upper bounds).  What it adds is baked in the next round; :data:`MAX_REPAIR_ROUNDS`
bounds the rounds.  Where a baked impostor turns out slower than its node's geometry in a CPV, it
is no longer drawn there (the geometry is), so a round never leaves a CPV slower than the plain
scene; an impostor left in no CPV is kept in the database with ``"cpvs": 0``.

Covered pixels keep their estimate (the bounding-sphere disc of the replaced elements, at most a
frame): a baked impostor's pixels depend on the view, and the estimate is conservative for the
layered and tdm techniques, whose quads lie inside their part's bounds.

The state pickles (:meth:`PlannerState.dumps`) with a format tag, so a worker other than the one
that planned can run the round.  Only farfield writes these bytes (the service's blob store); they
are never read from a user.
"""

from __future__ import annotations

import math
import pickle
from dataclasses import asdict, dataclass, field

import numpy as np

from farfield.core.placement.candidates import KIND_NAMES, LOD, OUTSIDE_SPHERE, Candidates
from farfield.core.placement.greedy import Greedy
from farfield.core.placement.hierarchy import Elements, Hierarchy, PlacementError
from farfield.core.placement.result import Placement
from farfield.core.placement.view_space import FACE_NAMES, ProblemViews
from farfield.core.scene import Scene

STATE_FORMAT = "farfield-planner-state"
STATE_VERSION = 1
MAX_REPAIR_ROUNDS = 3
BAKED_FIGURES = ("quads", "texture_bytes")


def scene_summary(scene: Scene, elements: Elements) -> dict:
    """What a placement document says of its scene (kept instead of the scene itself)."""
    return {
        "source": scene.source, "content_hash": scene.content_hash, "objects": scene.object_count, "triangles": scene.triangle_count,
        "split": elements.split_counts(scene),
    }  # fmt: skip


def _plain(options) -> dict:
    """A technique's Options as the placement document holds them (tuples as lists)."""
    return {k: (v if not isinstance(v, tuple) else list(v)) for k, v in asdict(options).items()}


@dataclass(frozen=True, slots=True)
class RepairRound:
    """One check-and-repair round: CPVs over ``t_max`` with the baked figures, before the greedy
    resumed; the impostor ids it added (to bake); the placement after it."""

    round: int
    cpvs_over: int
    added: list[int]
    placement: Placement

    correction: dict | None = None
    mode: str = "resumed"  # the greedy resumes (kept in the document for its readers)

    def to_dict(self) -> dict:
        return {
            "round": self.round,
            "cpvs_over": self.cpvs_over,
            "added": list(self.added),
            "correction": self.correction,
            "mode": self.mode,
        }


@dataclass(eq=False)
class PlannerState:
    """Everything :func:`farfield.core.placement.planner.place` computed, and the rounds since."""

    scene: dict  # scene_summary
    elements: Elements
    hierarchy: Hierarchy
    pv: ProblemViews
    cand: Candidates
    greedy: Greedy
    settings: object  # farfield.core.placement.planner.PlacementSettings
    options: object  # the technique's Options
    technique: str
    lo: np.ndarray
    hi: np.ndarray
    cpv_size: float
    seconds: dict
    ids: dict = field(default_factory=dict)  # candidate -> stable impostor id
    baked: dict = field(default_factory=dict)  # impostor id -> {"quads", "texture_bytes"}
    estimated: dict = field(default_factory=dict)  # impostor id -> its estimates before it was baked
    rounds: list = field(default_factory=list)
    first: dict | None = None  # every candidate's first estimates (quads, memory), before any correction
    correction: dict | None = None  # the last ratios of baked to estimated figures
    sources: tuple = ()  # the technique of each candidate source (Candidates.source); (): all ``technique``
    also: dict | None = None  # the other techniques' Options by name (PlacementSettings.also)

    # --- persistence ---------------------------------------------------------------------------

    def dumps(self) -> bytes:
        return pickle.dumps(
            {"format": STATE_FORMAT, "version": STATE_VERSION, "state": self}, protocol=pickle.HIGHEST_PROTOCOL
        )

    @classmethod
    def loads(cls, data: bytes) -> PlannerState:
        try:
            doc = pickle.loads(data)  # farfield's own blob, never a user's
        except Exception as error:  # noqa: BLE001 - any unpickling failure means the same
            raise PlacementError(
                f"the stored planner state could not be read: {type(error).__name__}: {error}"
            ) from error
        if not isinstance(doc, dict) or doc.get("format") != STATE_FORMAT or doc.get("version") != STATE_VERSION:
            raise PlacementError(f"the stored planner state is not {STATE_FORMAT} version {STATE_VERSION}")
        state = doc["state"]
        # Fields added since the state was written (slotted dataclasses unpickle without them):
        # the values its candidates were made with.
        for holder, name, value in (
            (state.settings, "max_impostor_bytes", math.inf),
            (state.settings, "visibility", False),
            (state.settings.model, "quads_exponent", 0.0),
            (state.cand, "source", None),
            (state.settings, "also", None),
            (state.settings, "lod", False),
            (state.cand, "prototype", None),
            (state.cand, "prototypes", ()),
            (state.cand, "scale", None),
        ):
            if not hasattr(holder, name):
                object.__setattr__(holder, name, value)
        if not hasattr(state.greedy, "atlas"):  # a greedy from before shared atlases: none
            state.greedy.atlas = np.full(state.cand.count, -1, dtype=np.int64)
            state.greedy.atlas_users = {}
        return state

    # --- ids ---------------------------------------------------------------------------------

    def _assign_ids(self) -> None:
        """Give every drawn impostor whose candidate has no id the next one, in the order chosen."""
        for order, imp in enumerate(self.greedy.chosen):
            if order not in self.greedy.deleted and imp.candidate not in self.ids:
                self.ids[imp.candidate] = len(self.ids)

    def candidate_of(self, impostor_id: int) -> int:
        for candidate, i in self.ids.items():
            if i == impostor_id:
                return candidate
        raise PlacementError(f"the placement has no impostor {impostor_id}")

    def _drawn(self) -> dict[int, int]:
        """Candidate -> greedy order of every impostor drawn somewhere."""
        return {
            imp.candidate: order for order, imp in enumerate(self.greedy.chosen) if order not in self.greedy.deleted
        }

    # --- repair --------------------------------------------------------------------------------

    def repair(self, baked: dict[int, dict], extend: bool = True) -> RepairRound:
        """Put the real figures of the impostors baked since the last round (``baked``: impostor id
        -> the bundle's stats, of which ``quads`` and ``texture_bytes`` are used) in place of their
        estimates, correct every candidate not baked by the estimates' bias so far, and go on with
        the greedy for the CPVs over ``t_max``, resumed with the candidates not chosen.  (Running
        it again from the start when the first estimates were far off discarded most of what was
        baked and, on a dense city, chose one impostor over the whole view space instead.)  Returns the round, with the ids of the impostors
        it added (to bake; none: the placement holds with what is baked).  ``extend=False``
        (the last round) puts the figures in and adds nothing: the CPVs' times and statuses are
        then those of what is baked."""
        self._assign_ids()
        model, greedy, cand = self.settings.model, self.greedy, self.cand
        if self.first is None:  # every candidate's estimates before any baked figure or correction
            self.first = {"quads": cand.quads.copy(), "memory": cand.memory.copy()}
        drawn = self._drawn()
        for impostor_id, stats in sorted(baked.items()):
            impostor_id = int(impostor_id)
            if impostor_id in self.baked:
                continue  # its figures are in place already (a round repeated after a lost worker)
            i = self.candidate_of(impostor_id)
            if int(cand.kind[i]) == OUTSIDE_SPHERE and "quads" not in stats:  # one card: its estimate is its figure
                stats = {**stats, "quads": float(cand.quads[i])}
            missing = [k for k in BAKED_FIGURES if not isinstance(stats.get(k), (int, float))]
            if missing:
                raise PlacementError(f"the baked stats of impostor {impostor_id} lack {missing}")
            # The estimate before any correction: the bias is measured against what the corrections scale.
            self.estimated[impostor_id] = {
                "quads": float(self.first["quads"][i]),
                "memory_bytes": float(self.first["memory"][i]),
            }
            delta = float(
                model.impostor_time(0.0, float(stats["quads"])) - model.impostor_time(0.0, float(cand.quads[i]))
            )
            cand.quads[i] = float(stats["quads"])
            cand.memory[i] = max(float(stats["texture_bytes"]), 1.0)
            a, b = cand.served_offsets[i], cand.served_offsets[i + 1]
            cand.ti[a:b] += delta  # greedy.ti is this array
            self.baked[impostor_id] = {k: float(stats[k]) for k in BAKED_FIGURES}
            if i not in drawn:
                continue
            chosen = greedy.chosen[drawn[i]]
            keys = []
            for p, (g_p, t_p) in chosen.cpvs.items():
                chosen.cpvs[p] = (g_p, t_p + delta)
                greedy.t[p] += delta
                keys.append(p * int(greedy.nodes) + chosen.node)
            if keys:
                at = np.searchsorted(greedy._keys, np.asarray(keys, dtype=np.int64))
                greedy._saved[at] -= delta
                greedy._cum = None
            self._withdraw_where_slower(drawn[i])
        self._correct_not_baked()
        over = int(np.sum(greedy.t > greedy.t_max * (1.0 + 1e-9)))
        known = len(self.ids)
        if over and extend:
            greedy.run()
        self._assign_ids()
        added = sorted(i for i in self.ids.values() if i >= known)
        step = RepairRound(len(self.rounds) + 1, over, added, self.placement(), self.correction, "resumed")
        self.rounds.append(step.to_dict())
        return step

    def _withdraw_where_slower(self, order: int) -> None:
        """Stop drawing impostor ``order`` in the CPVs where, with its real figures, it is slower
        than the geometry of its node (``g_p <= t_p``): the node is drawn as geometry there again
        (``t += g_p - t_p``; the descendants' impostors it replaced stay replaced, their savings
        were part of ``t`` before), so a round never leaves a CPV slower than before it.  An
        impostor left in no CPV is deleted (§5.7.5), and its memory regained."""
        greedy = self.greedy
        chosen = greedy.chosen[order]
        slower = [p for p, (g_p, t_p) in chosen.cpvs.items() if g_p <= t_p]
        if not slower:
            return
        keys = []
        for p in slower:
            g_p, t_p = chosen.cpvs.pop(p)
            greedy.t[p] += g_p - t_p
            greedy.drawn[p] = [k for k in greedy.drawn[p] if k != order]
            keys.append(p * int(greedy.nodes) + chosen.node)
        keep = ~np.isin(greedy._keys, np.asarray(keys, dtype=np.int64))
        greedy._keys, greedy._saved = greedy._keys[keep], greedy._saved[keep]
        greedy._cum = None
        if not chosen.cpvs:
            greedy.deleted.add(order)

    def _correct_not_baked(self) -> None:
        """Scale the quads and memory of every candidate not baked by the median ratio of baked to
        estimated figures so far (the estimates' bias on this scene, e.g. box growing cutting more
        quads per layer than on the calibration scenes), so the greedy ranks and counts with figures
        like those its additions will have once baked; each candidate's figures are scaled from
        their first estimate, so repeated rounds do not compound."""
        if not self.baked:
            return
        cand, model = self.cand, self.settings.model
        source = cand.source if cand.source is not None else np.zeros(cand.count, dtype=np.int64)
        free = np.ones(cand.count, dtype=bool)
        free[[self.candidate_of(i) for i in self.baked]] = False
        # Per source of candidates (a technique): its own bias; a source with nothing baked keeps its estimates.
        scale = {"quads": np.ones(cand.count), "memory": np.ones(cand.count)}
        ratios = {}
        for s in np.unique(source):
            mine = [i for i in self.baked if source[self.candidate_of(i)] == s]
            if not mine:
                continue
            ratio = {
                k: float(np.median([self.baked[i][b] / max(self.estimated[i][e], 1e-12) for i in mine]))
                for k, b, e in (("quads", "quads", "quads"), ("memory", "texture_bytes", "memory_bytes"))
            }  # fmt: skip
            for k in scale:
                scale[k][source == s] = ratio[k]
            ratios[self.technique_of_source(int(s))] = ratio
        quads = np.where(free, self.first["quads"] * scale["quads"], cand.quads)
        delta = np.asarray(model.impostor_time(0.0, quads), dtype=np.float64) - np.asarray(
            model.impostor_time(0.0, cand.quads), dtype=np.float64
        )
        cand.ti[:] += np.repeat(np.where(free, delta, 0.0), np.diff(cand.served_offsets))
        cand.quads[:] = quads
        cand.memory[:] = np.where(free, np.maximum(self.first["memory"] * scale["memory"], 1.0), cand.memory)
        # A candidate the correction makes larger than max_impostor_bytes gains nothing any more.
        over = np.repeat(free & (cand.memory > self.settings.max_impostor_bytes), np.diff(cand.served_offsets))
        cand.ti[:] = np.where(over, np.maximum(cand.ti, cand.g), cand.ti)
        # The placement's own technique's ratios (as before mixed candidates), and every technique's.
        self.correction = dict(ratios.get(self.technique) or next(iter(ratios.values())))
        if len(self.sources) > 1:
            self.correction["by_technique"] = ratios

    @property
    def mixed(self) -> bool:
        """Whether candidates of several kinds competed (``also``, or simplified geometry)."""
        return bool(self.also) or bool(getattr(self.settings, "lod", False))

    def technique_of_source(self, source: int) -> str:
        """The technique whose candidates ``source`` (Candidates.source) holds."""
        return (self.sources[source] if source < len(self.sources) else None) or self.technique

    # --- the result ----------------------------------------------------------------------------

    def placement(self) -> Placement:
        """The placement as it stands (:class:`~farfield.core.placement.result.Placement`)."""
        self._assign_ids()
        greedy, cand, pv, hierarchy, elements, settings = (
            self.greedy,
            self.cand,
            self.pv,
            self.hierarchy,
            self.elements,
            self.settings,
        )
        impostors = []
        drawn = self._drawn()
        for i, impostor_id in sorted(self.ids.items(), key=lambda kv: kv[1]):
            imp = greedy.chosen[drawn[i]] if i in drawn else None
            node = int(cand.node[i])
            names = [elements.names[e] for e in np.sort(hierarchy.elements_of(node))]
            entry = {
                "id": impostor_id,
                "node": node,
                "objects": names,
                "cell": cand.cells[i].to_dict(),
                "technique": self.technique_of_source(cand.source_of(i)),
                "layers_estimated": float(cand.layers[i]),
                "texels_per_layer": float(cand.texels[i]),
                "quads_estimated": self.estimated.get(impostor_id, {}).get("quads", float(cand.quads[i])),
                "memory_bytes_estimated": self.estimated.get(impostor_id, {}).get(
                    "memory_bytes", float(cand.memory[i])
                ),
                "memory_bytes": float(cand.memory[i]),  # the baked texture bytes, once baked
                "cpvs": len(imp.cpvs) if imp else 0,
                "time_max": max((t for _, t in imp.cpvs.values()), default=0.0) if imp else 0.0,
            }
            if impostor_id in self.baked:
                entry["baked"] = dict(self.baked[impostor_id])
            if self.mixed:  # mixed candidates: which kind of cell each is (an octahedral one's: outside-sphere)
                entry["kind"] = KIND_NAMES[int(cand.kind[i])]
            if int(cand.kind[i]) == LOD:  # simplified geometry: its level and triangles
                entry |= {"level": int(cand.layers[i]), "triangles": int(cand.texels[i])}
            if cand.atlas_of(i) >= 0:  # an instance drawing from its prototype's atlas (owner: below)
                key = cand.prototypes[cand.atlas_of(i)][1]
                entry["atlas"] = {"prototype": key, "scale": float(cand.scale[i]), "shared": cand.atlas_of(i)}
            impostors.append(entry)
        shared_atlases = _share_atlases(impostors)
        solvable = ~pv.unsolvable
        after = np.where(solvable, greedy.t, pv.time)
        unsolved = solvable & (after > settings.t_max * (1.0 + 1e-9))
        cpvs = []
        for p in range(pv.count):
            status = "unsolvable" if pv.unsolvable[p] else ("unsolved" if unsolved[p] else "solved")
            r = int(pv.cpv_region[p])
            v = pv.cpv_vdi[p]
            cpvs.append({
                "id": p,
                "region": [pv.region_lo[r].tolist(), pv.region_hi[r].tolist()],
                "vdi": {"face": FACE_NAMES[v.face], "level": v.level, "i": v.i, "j": v.j},
                "time_before": float(pv.time[p]),
                "time_after": float(after[p]),
                "impostors": sorted(self.ids[greedy.chosen[k].candidate] for k in greedy.drawn[p]),
                "status": status,
            })  # fmt: skip
        blame = []
        by_region: dict[int, list[int]] = {}
        for p in np.flatnonzero(pv.unsolvable):
            by_region.setdefault(int(pv.cpv_region[p]), []).append(int(p))
        for r in sorted(by_region):
            cpv_ids = by_region[r]
            worst = max(cpv_ids, key=lambda p: (pv.fixed_time[p], -p))
            a, b = pv.offsets[worst], pv.offsets[worst + 1]
            ids = hierarchy.order[pv.positions[a:b][pv.entry_fixed[a:b]]]
            blame.append({
                "region": [pv.region_lo[r].tolist(), pv.region_hi[r].tolist()],
                "cpvs": len(cpv_ids),
                "fixed_time": float(pv.fixed_time[worst]),
                "elements": sorted(elements.names[e] for e in ids),
            })  # fmt: skip
        drawn = [imp for imp in impostors if imp["cpvs"]]
        by_technique: dict[str, dict] = {}
        for imp in drawn:
            row = by_technique.setdefault(imp["technique"], {"impostors": 0, "memory_bytes": 0.0, "cpvs": 0})
            row["impostors"] += 1
            row["memory_bytes"] += _charged(imp)
            row["cpvs"] += int(imp["cpvs"])
        summary = {
            "t_max": float(settings.t_max),
            "unit": settings.model.unit,
            "cpvs": pv.count,
            "cpvs_solved": int(np.sum(solvable & ~unsolved)),
            "cpvs_unsolved": int(unsolved.sum()),
            "cpvs_unsolvable": int(pv.unsolvable.sum()),
            "candidates": cand.count,
            "candidates_considered": int(cand.stats["considered"]),
            "candidates_refused_by_technique": int(cand.stats["refused_by_technique"]),
            "candidates_refused_by_memory": int(cand.stats.get("refused_by_memory", 0)),
            "impostors": len(drawn),
            "impostors_unused": len(impostors) - len(drawn),
            "impostors_deleted": len(greedy.deleted),
            "memory_bytes": float(sum(_charged(imp) for imp in drawn)),  # each shared atlas once
            "worst_before": float(pv.time.max()) if pv.count else 0.0,
            "worst_after": float(after.max()) if pv.count else 0.0,
            "worst_after_solvable": float(after[solvable].max()) if solvable.any() else 0.0,
            "leaf_regions_with_cpvs": int(pv.region_lo.shape[0]),
            "vdis_evaluated": int(pv.stats["vdis_evaluated"]),
            "hierarchy_nodes": hierarchy.count,
            "elements": elements.count,
            "rescored": greedy.rescored,
            "rounds": len(self.rounds),
        }
        if self.mixed:  # mixed candidates: what was chosen of each technique
            summary["by_technique"] = dict(sorted(by_technique.items()))
        if "lod_nodes_simplified" in cand.stats:
            summary["lod_nodes_simplified"] = int(cand.stats["lod_nodes_simplified"])
        if shared_atlases:
            summary["shared_atlases"] = shared_atlases
        parameters = {
            "scene": {k: v for k, v in self.scene.items() if k != "split"},
            "view_space": [self.lo.tolist(), self.hi.tolist()],
            "t_max": float(settings.t_max),
            "cost_model": settings.model.to_dict(),
            "technique": self.technique,
            "options": _plain(self.options),
            "cpv_size": float(self.cpv_size),
            "vdi_deg": float(settings.vdi_deg),
            "depth_complexity": None
            if math.isinf(settings.depth_complexity)
            else float(settings.depth_complexity),  # None: no cap (JSON has no infinity)
            "cells": settings.cells,
            "leaf_size": settings.leaf_size,
            "max_impostor_bytes": None
            if math.isinf(settings.max_impostor_bytes)
            else float(settings.max_impostor_bytes),  # None: no cap
            "apex_angles_deg": [float(a) for a in settings.apex_angles_deg],
            "direction_step_deg": float(settings.direction_step_deg),
            "distance_steps": int(settings.distance_steps),
            "visibility": {"kind": "sampled potentially visible sets", **pv.stats["visibility"]}
            if "visibility" in pv.stats
            else "none (no occlusion culling; seed 000 Table 5.1 test 16 setting)",
        }
        if self.also:  # the other techniques whose candidates competed, with their options
            parameters["also"] = {name: _plain(o) for name, o in self.also.items()}
        if getattr(settings, "lod", False):  # simplified geometry competed (farfield.core.placement.lod)
            parameters["lod"] = True
        return Placement(
            parameters=parameters,
            elements={
                "count": elements.count,
                "cluster_triangles": elements.cluster_triangles,
                "split": self.scene["split"],
            },
            impostors=impostors,
            cpvs=cpvs,
            unsolvable=blame,
            summary=summary,
            seconds=self.seconds,
            visibility=pv.stats.get("pvs"),  # the stored PVS of a placement planned with visibility
        )


def _share_atlases(impostors: list[dict]) -> list[dict]:
    """Give every impostor drawing from a shared atlas (its ``atlas`` entry) the id of the drawn
    impostor that holds the atlas (``atlas["owner"]``: the first drawn one of that atlas by id; the
    others' memory is not counted again, :func:`_charged`); returns one row per shared atlas drawn:
    its prototype, owner, the ids drawing from it and its bytes."""
    rows: dict[int, dict] = {}
    for imp in impostors:
        atlas = imp.get("atlas")
        if atlas is None or not imp["cpvs"]:
            continue
        row = rows.setdefault(atlas["shared"], {"prototype": atlas["prototype"], "technique": imp["technique"],
                                                "owner": imp["id"], "impostors": [],
                                                "memory_bytes": float(imp["memory_bytes"])})  # fmt: skip
        row["impostors"].append(imp["id"])
    for imp in impostors:
        atlas = imp.get("atlas")
        if atlas is not None:
            atlas["owner"] = rows[atlas["shared"]]["owner"] if atlas["shared"] in rows else None
    return [rows[k] for k in sorted(rows)]


def _charged(imp: dict) -> float:
    """The memory impostor ``imp`` adds to its placement: its bytes, or 0 where it draws from a
    shared atlas another impostor holds."""
    atlas = imp.get("atlas")
    if atlas is not None and atlas.get("owner") not in (None, imp["id"]):
        return 0.0
    return float(imp["memory_bytes"])
