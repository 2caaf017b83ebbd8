"""State across frames for the frame loop: each stateful deformable starts a frame from the
animator's shape plus the offsets carried from the previous frame (`acra.relax`), and the output
layer records what it carries (``acra:state:*``, docs/usd-schema.md §4).

A deformable is *stateful* when its ``acra:relax`` is below 1 at some sample or its
``acra:plasticity`` is above 0 (`pipeline.model.Controls.stateful`); any other deformable is
processed exactly as by the stateless loop, and nothing of this module touches it.

Frames of a stateful run go in order. A run that starts after the stage's first frame gets the
state carried into its first frame by `carried_at` (the frames from the stage's start recomputed,
the default) or from a previous run's output layer (`read_carried`), handed to
`pipeline.frames.run_frames` as ``initial``; both give, at every frame, what a whole run gives.
A farm chunk does the same with the previous chunk's last carried state.

Volume preservation (``acra:preserveVolume``) is applied here too, after every response of the
frame (`Carry.after_response`, `acra.volume.bulge`); it carries nothing across frames.
"""

from __future__ import annotations

import numpy as np
from pxr import Usd, Vt

from acra import hspline as H
from acra import relax
from acra import volume
from acra.basis import Direction
from acra.tessellate import GridTopology, display_topology
from pipeline import shape as S
from pipeline import usdio
from pipeline import output_layer
from pipeline.model import DeformableModel, SceneModel

__all__ = ["Carry", "for_run", "carried_at", "carried_values", "read_carried", "zero_carried"]


NEGLIGIBLE = 1e-9  # an elastic field below this fraction of the object's size is released in full


def zero_carried(scene: SceneModel, model: DeformableModel) -> relax.Carried:
    """Nothing carried: zero fields shaped like the deformable."""
    z = relax.zero_field(usdio.surface_template(scene, model))
    return relax.Carried(z, z)


class Carry:
    """The carried state of a run's deformables, frame by frame (the frame loop's hooks).

    ``begin(frame, surfaces)`` gives the surfaces the frame starts from (`acra.relax.begin`);
    ``after_response`` keeps an object's volume after each response; ``end(frame, surfaces)``
    absorbs the frame's responses and returns what each object carries out of it. The contact
    rewinding keeps following the animator's motion without the carried offsets (see
    docs/algorithm.md, "State across frames").
    """

    def __init__(self, scene: SceneModel, initial: list | None = None, density: int = 8):
        self.models = scene.deformables
        self.density = density
        self.previous: list = [None] * len(self.models)  # each object's final surface of the last frame
        self.last_start: list = [None] * len(self.models)  # (animator surface, plastic field, start)
        self.on = [m.controls.stateful for m in self.models]
        if initial is None:
            initial = [None] * len(self.models)
        self.carried = [
            (c if c is not None else zero_carried(scene, m)) if on else None
            for m, on, c in zip(self.models, self.on, initial)
        ]
        self.released: list = [None] * len(self.models)
        self.started: list = [None] * len(self.models)
        self.keeps_volume = [m.controls.preserve_volume > 0.0 for m in self.models]
        self.targets: list = [None] * len(self.models)  # the animator's display volume at the frame
        self.measures: list = [None] * len(self.models)  # "volume" (closed) or "area" (open sheet)
        self.dents: list = [None] * len(self.models)  # display samples the frame's responses moved
        self._topologies: list = [None] * len(self.models)  # `topology`, built on first use

    @property
    def active(self) -> bool:
        """Whether any object carries state."""
        return any(self.on)

    def begin(self, frame: int, surfaces: list[H.HSpline]) -> list[H.HSpline]:
        """``S_f`` of every object from the animator's ``A_f`` (``surfaces``, scene order)."""
        out = list(surfaces)
        for i, keep in enumerate(self.keeps_volume):
            if keep:
                topo = self.topology(i)
                self.measures[i] = "volume" if volume.encloses(surfaces[i]) else "area"
                size = volume.MEASURES[self.measures[i]][0]
                self.targets[i] = size(H.evaluate(surfaces[i], topo.u, topo.v).points, volume.triangles(topo))
                self.dents[i] = np.zeros(topo.u.size, bool)
        for i, on in enumerate(self.on):
            if on:
                rates = self.models[i].controls.relax_at(float(frame))
                carried = self.carried[i]
                if not relax.is_zero(carried.elastic) and (
                        relax.level_magnitudes(carried.elastic).max() <= NEGLIGIBLE * surfaces[i].size()):
                    # released to below anything float32 display points can show: it is gone
                    carried = relax.Carried(relax.zero_field(carried.elastic), carried.plastic)
                last = self.last_start[i]
                if (last is not None and last[0] is surfaces[i] and last[1] is carried.plastic
                        and relax.is_zero(carried.elastic)):
                    # nothing changed since the last frame's start (the same animator surface, the
                    # same kept offsets, nothing left to release): the same surface object, so
                    # its shape data and display are reused as in the stateless loop
                    out[i], self.released[i] = last[2], carried
                else:
                    out[i], self.released[i] = relax.begin(surfaces[i], carried, rates)
                self.last_start[i] = (surfaces[i], carried.plastic, out[i])
                self.started[i] = out[i]
                if out[i] is not surfaces[i] and self.previous[i] is not None and out[i] is not self.previous[i]:
                    # the last frame's surface differs from this start only where the carried
                    # offsets live (and where the animator's CVs moved): its collision grids,
                    # hull boxes and display samples serve everywhere else (`shape.Shape`)
                    prev = self.previous[i]
                    det = None
                    if prev.depth > 1:
                        det = H.details(out[i], since=(prev, S.shape_of(prev, self.density).details,
                                                       H.changed_patches(prev, out[i])))
                    S.seed_details(out[i], det, self.density, parent=prev)
        return out

    def topology(self, i: int) -> GridTopology:
        """The tessellation object ``i``'s volume (or area) is kept on: ``acra:samples`` steps
        per edge of a patch of its finest absorbing level, everywhere. A response's dent lives on
        that level, where the run's display (`pipeline.display`) has that density too, so the
        measure kept here is the measure the output shows to the tessellation's error outside
        the dent, which the animator's surface and the responded one share."""
        if self._topologies[i] is None:
            m = self.models[i]
            level = int(np.nonzero(m.controls.absorption > 0)[0].max(initial=0))
            u, v = Direction(m.nu, m.u_periodic), Direction(m.nv, m.v_periodic)
            self._topologies[i] = display_topology(u, v, m.controls.samples << level)
        return self._topologies[i]

    def after_response(self, i: int, parent: H.HSpline, responded: H.HSpline) -> H.HSpline:
        """Object ``i``'s responded surface with its volume (a closed object) or area (an open
        sheet) restored (``acra:preserveVolume``): the display samples the response moved join
        the frame's dent, and the bulge level's CVs move around it (`acra.volume.bulge`) until
        the display mesh's measure is ``V + s (V_animator - V)`` (strength ``s``). The frame loop's next round detects again,
        so a bulge that touched something is answered like any other penetration, and the
        residual the run reports is measured after it."""
        if not self.keeps_volume[i]:
            return responded
        c = self.models[i].controls
        topo = self.topology(i)
        before = H.evaluate(parent, topo.u, topo.v).points
        after = H.evaluate(responded, topo.u, topo.v).points
        size = responded.size()
        moved = np.linalg.norm(after - before, axis=1)
        # the dent: what this response moved by more than a tenth of its largest move (and more
        # than 1e-3 of the size); a coarse level's response moves the whole object a little,
        # and a dent that took everything would leave nothing to bulge
        self.dents[i] |= moved > max(1e-3 * size, 0.1 * moved.max(initial=0.0))
        weights = volume.bulge_weights(after, self.dents[i], c.bulge_falloff * size)
        now = volume.MEASURES[self.measures[i]][0](after, volume.triangles(topo))
        goal = now + c.preserve_volume * (self.targets[i] - now)
        out, _ = volume.bulge(responded, topo, goal, c.bulge_level, weights, measure=self.measures[i])
        return out

    def volume_targets(self) -> dict:
        """``{path: (measure, the animator's display volume or area at the frame)}`` of the
        objects keeping theirs (``measure`` is ``"volume"`` or ``"area"``)."""
        return {m.path: (self.measures[i], self.targets[i]) for i, m in enumerate(self.models) if self.keeps_volume[i]}

    def end(self, frame: int, surfaces: list[H.HSpline]) -> list:
        """What every object carries out of the frame (``None`` for a stateless one), given the
        frame's final surfaces ``R_f``."""
        for i, on in enumerate(self.on):
            if on:
                p = self.models[i].controls.plasticity
                p = np.zeros(surfaces[i].depth) if p is None else p
                self.carried[i] = relax.absorb(self.released[i], self.started[i], surfaces[i], p)
                self.previous[i] = surfaces[i]
        return list(self.carried)


def for_run(stage: Usd.Stage, scene: SceneModel, frames: list[int], options, initial: list | None = None) -> Carry:
    """The `Carry` of a run over ``frames``: from ``initial`` if given, else recomputed from the
    stage's start (`carried_at`) when the run starts after it. Raises ``ValueError`` when a
    stateful run's frames are not consecutive and increasing (the state would skip frames)."""
    carry = Carry(scene, initial, options.density)
    if not carry.active or not frames:
        return carry
    if any(b != a + 1 for a, b in zip(frames, frames[1:])):
        raise ValueError("a run with state across frames needs consecutive increasing frames")
    if initial is None and frames[0] > scene.start:
        carry = Carry(scene, carried_at(stage, scene, frames[0] - 1, options), options.density)
    return carry


def carried_at(stage: Usd.Stage, scene: SceneModel, frame: int, options=None) -> list:
    """What every deformable carries out of ``frame`` (``None`` for a stateless one), recomputed
    by running the frames from the stage's start to ``frame``."""
    from pipeline import frames as F

    if frame < scene.start:
        return [zero_carried(scene, m) if m.controls.stateful else None for m in scene.deformables]
    options = F.RunOptions() if options is None else options
    result, _ = F.respond_frames(stage, scene, list(range(scene.start, frame + 1)), options)
    return [result.frames[frame][m.path].carried for m in scene.deformables]


def _per_level_rows(hs: H.HSpline, keep: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """``(ju, jv)`` of the level-``k`` CVs selected by ``keep`` and their rows."""
    lev = hs.level(k)
    rows = np.nonzero(keep)[0]
    ncv = hs.v.cvs(k)
    keys = lev.cv_keys[rows]
    return np.stack([keys // ncv, keys % ncv], axis=1), rows


def carried_values(model: DeformableModel, carried: relax.Carried) -> dict:
    """The ``acra:state:*`` Vt values of one object's carried state (float64: exact round trip)."""
    e, p = relax.aligned(carried.elastic, carried.plastic)
    arrays = H.to_arrays(e)
    levels, cvs, eo, po = [], [], [], []
    for k in range(1, e.depth):
        keep = np.any(e.level(k).offsets != 0.0, axis=1) | np.any(p.level(k).offsets != 0.0, axis=1)
        idx, rows = _per_level_rows(e, keep, k)
        levels.append(np.full(len(rows), k, np.int32))
        cvs.append(idx)
        eo.append(e.level(k).offsets[rows])
        po.append(p.level(k).offsets[rows])

    def cat(xs: list, shape: tuple, dt) -> np.ndarray:
        return np.ascontiguousarray(np.concatenate(xs) if xs else np.zeros(shape), dtype=dt).reshape((-1,) + shape[1:])

    return {
        "acra:state:patchLevel": Vt.IntArray.FromNumpy(np.ascontiguousarray(arrays.patch_level, dtype=np.int32)),
        "acra:state:patches": Vt.Vec2iArray.FromNumpy(np.ascontiguousarray(arrays.patches, dtype=np.int32).reshape(-1, 2)),
        "acra:state:elasticCvs": Vt.Vec3dArray.FromNumpy(usdio.cvs_to_flat(np.asarray(e.cvs, dtype=np.float64))),
        "acra:state:plasticCvs": Vt.Vec3dArray.FromNumpy(usdio.cvs_to_flat(np.asarray(p.cvs, dtype=np.float64))),
        "acra:state:offsetLevel": Vt.IntArray.FromNumpy(cat(levels, (0,), np.int32)),
        "acra:state:offsetCvs": Vt.Vec2iArray.FromNumpy(cat(cvs, (0, 2), np.int32)),
        "acra:state:elasticOffsets": Vt.Vec3dArray.FromNumpy(cat(eo, (0, 3), np.float64)),
        "acra:state:plasticOffsets": Vt.Vec3dArray.FromNumpy(cat(po, (0, 3), np.float64)),
    }


def read_carried(output: Usd.Stage, scene: SceneModel, frame: int, stage: Usd.Stage | None = None) -> list:
    """What every deformable carries out of ``frame`` as a previous run's output layer recorded it
    (``output`` opened on that layer; ``None`` for a stateless deformable).

    With ``stage`` (the input this run reads), the layer must match it: the surface it wrote at
    ``frame`` (``acra:response:*``) must be the input's animator surface there plus the carried
    fields (``R_f = A_f ⊕ P_f ⊕ E_f``, `acra.relax`) to 1e-9 of the object's size, else the input
    changed since that run and its state cannot be resumed.

    Raises ``ValueError`` naming the prim when the layer does not fit ``scene`` (no state recorded
    at ``frame``, arrays that do not match the object's grid and levels, or a mismatch as above).
    """
    out = []
    for m in scene.deformables:
        if not m.controls.stateful:
            out.append(None)
            continue
        prim = output.GetPrimAtPath(m.path)
        attr = prim.GetAttribute("acra:state:elasticCvs") if prim else None
        if not attr or float(frame) not in attr.GetTimeSamples():
            raise ValueError(f"{m.path}: no acra:state recorded at frame {frame} in {output.GetRootLayer().identifier}")
        get = lambda n, dt, shape: np.array(prim.GetAttribute(n).Get(float(frame)), dtype=dt).reshape(shape)  # noqa: E731
        zero = zero_carried(scene, m).elastic
        ecvs, pcvs = get("acra:state:elasticCvs", np.float64, (-1, 3)), get("acra:state:plasticCvs", np.float64, (-1, 3))
        if len(ecvs) != m.nu * m.nv or len(pcvs) != m.nu * m.nv:
            raise ValueError(f"{m.path}: acra:state CVs at frame {frame} do not match the grid {m.nu}x{m.nv}")
        structure = H.from_arrays(zero, H.HierarchyArrays(
            get("acra:state:patchLevel", np.int32, (-1,)), get("acra:state:patches", np.int32, (-1, 2)),
            np.zeros(0, np.int32), np.zeros((0, 2), np.int32), np.zeros((0, 3))))
        levels = get("acra:state:offsetLevel", np.int32, (-1,))
        cvs = get("acra:state:offsetCvs", np.int32, (-1, 2))
        fields = []
        for grid, name in ((ecvs, "acra:state:elasticOffsets"), (pcvs, "acra:state:plasticOffsets")):
            hs = H.from_arrays(structure, H.HierarchyArrays(np.zeros(0, np.int32), np.zeros((0, 2), np.int32),
                                                            levels, cvs, get(name, np.float64, (-1, 3))))
            fields.append(H.HSpline(usdio.flat_to_cvs(grid, m.nu, m.nv), hs.u, hs.v, hs.depth, hs.fine))
        carried = relax.Carried(*fields)
        if stage is not None:
            animator = usdio.state_at(stage, scene, float(frame))[0][scene.deformables.index(m)].surface
            written = output_layer.read_output_hierarchy(output, m.path, float(frame))
            gap = relax.level_magnitudes(relax.difference(written, relax.added(animator, carried.plastic, carried.elastic)))
            if gap.max() > 1e-9 * animator.size():
                raise ValueError(f"{m.path}: the acra:state recorded at frame {frame} does not match the input "
                                 f"(response off the input plus the carried state by {gap.max():.3g}): run from the start")
        out.append(carried)
    return out
