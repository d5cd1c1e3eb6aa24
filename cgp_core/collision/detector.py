"""Contact detection for one sub-step: broad phase → narrow phase → :class:`ContactSet`.

Three compiled stages, called in order from :meth:`CollisionDetector.detect`, which times each into
:attr:`CollisionDetector.profile` (:data:`STAGES`):

1. ``bounds`` — :func:`~cgp_core.collision.primitives.primitive_bounds`: the :class:`CollisionModel`'s
   primitives at the bodies' :class:`~.primitives.BodyMotion` → :class:`PrimitivePoses` (centres, AABBs grown by
   the speculative margins);
2. ``broad_phase`` — :func:`small_scene_pairs` for a handful of primitives, else the configured
   :mod:`.broadphase` function → :class:`Pairs` (the default, sweep and prune, hands a scene too dense for it to
   the grid: :data:`SWEEP_TESTS_PER_BOX`);
3. ``narrow_phase`` — :func:`narrow_phase`: one loop over the ground (:class:`GroundPlane`) and the candidate
   pairs, each handed to its shape pair's kernel in :mod:`.narrowphase` / :mod:`.box_box` → a
   :class:`ContactSet`;
4. ``convex_phase`` — only for a model with issue 25's shapes (convex hulls, compound bodies' parts, static
   meshes: :mod:`.convex_phase`, whose :class:`~.convex_phase.ShapeModel` numbers its primitives after the
   :class:`CollisionModel`'s): :func:`.convex_phase.pose_shapes` poses and bounds them in the ``bounds`` stage, one
   broad phase takes every primitive, the pairs of two of the :class:`CollisionModel`'s primitives go to
   :func:`narrow_phase` unchanged, every other pair and those shapes' ground contacts to
   :func:`.convex_phase.convex_phase`, whose contacts are appended (from :data:`CONVEX_SPLIT_MIN_PAIRS` pairs on in
   two calls at once, the second on the machine's second core: the same contacts);
5. ``time_of_impact`` — after the integrator (:meth:`CollisionDetector.sweep_fast_rotation`): bodies that turned
   fast next to fixed hulls, boxes or meshes are put back at their time of impact (:mod:`.convex_phase`).

A scene without issue 25's shapes runs stages 1–3 exactly as before (no cost, the same bits).

Speculative contacts (Catto, "Continuous collision", GDC 2013; Box2D v3).  A pair is reported not only when
it touches but whenever its gap may close within the coming sub-step: each body gets a *margin*

    margin = speculative_distance + h (|v| + |ω| · reach)

(``reach`` = farthest surface point from the COM, so ``h |ω| reach`` bounds how far a turning surface moves),
AABBs are grown by it, and a contact is kept when its separation is below the sum of the two margins (one
margin against the ground).  The solver then lets such a contact close its gap exactly and no further
(target normal velocity ``−separation / h``), which is what stops a fast sphere from tunnelling through the
ground or a thin wall: no speed limit for translation, as long as the motion over one sub-step is close to a
straight line.  Known limits: the contact points are those of the start-of-step pose, so a box spinning by a
large angle in one sub-step can still pass through a thin object (rotation is only bounded, not swept), and
a fast body grazing past another may feel a small "ghost" impulse from a speculative point it would have
missed.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np

from .. import second_core
from ..bodies import BodyModel, BodyState, Shape
from ..jit import StageProfile, njit
from .box_box import box_box_contacts
from .broadphase import DEFAULT_BROAD_PHASE, get_broad_phase, grid_kernel, sweep_and_prune_kernel, sweep_and_prune_pairs
from .carry import CarriedContacts, carried_contacts, carry
from .contacts import FEATURE_SLOTS, GROUND, ContactSet
from .convex_phase import (
    MESH_CANDIDATES,
    TOI_TARGET,
    TOI_TOLERANCE,
    ShapeModel,
    ShapePoses,
    build_shape_model,
    convex_phase,
    fast_turn_pairs,
    pose_shapes,
    sweep_times,
    tighten_hull_bounds,
)
from .materials import Ground, combine_friction, combine_restitution
from .narrowphase import (
    Box,
    Capsule,
    ContactBuffer,
    box_capsule_contacts,
    box_plane_contacts,
    capsule_capsule_contacts,
    capsule_plane_contacts,
    sphere_box_point,
    sphere_capsule_point,
    sphere_plane_point,
    sphere_sphere_point,
    write_point,
)
from .primitives import CollisionModel, PrimitivePoses, build_collision_model, primitive_bounds

#: default speculative distance [m]: contacts within this gap are kept even at rest, so a resting contact
#: does not flicker in and out (and lose its warm-start impulse) with the solver's tiny residual motion
DEFAULT_SPECULATIVE_DISTANCE = 0.002

#: contacts carried through a tick (``world.contact_detection: once_per_tick``): once a body's surface may have moved
#: by more than this share of the speculative distance since the contacts were detected, they are detected again
#: (CollisionDetector._moved).  Half: two bodies then close by less than one speculative distance, less than the sum
#: of their margins (each at least one), so no pair that a detection in every sub-step finds is missed
CARRY_SHARE = 0.5

#: up to this many primitives the broad phase tests every pair (compiled) whatever is configured
SMALL_SCENE = 64

#: the default broad phase's bound on the sweep's candidates, per box: past it the scene is dense along every axis
#: (a 3-D pile of thousands of bodies), the sweep gives up and the grid finds the pairs (the same pairs: both are
#: exact).  Measured on 10,000 spheres in a 22³ lattice: the sweep tests ~1,000 candidates per box, 156 ms a
#: call, the grid 29 ms; 2,000 compound bodies of 16 parts (32,000 boxes) ticked in 6.4 s with the sweep alone.
#: A sparse scene or a pile of a few thousand tests fewer than 64 a box and keeps the sweep (which is faster there).
SWEEP_TESTS_PER_BOX = 64
#: calls the grid then keeps the scene before the sweep is tried again (a pile that spreads out goes back to it):
#: one second of sub-steps at 60 Hz with 4 of them
GRID_CALLS = 240

#: most contact points one primitive pair (or a primitive and the ground) can give (box–box, box–plane)
MAX_POINTS_PER_PAIR = 4

SPHERE, BOX, CAPSULE = int(Shape.SPHERE), int(Shape.BOX), int(Shape.CAPSULE)

#: an empty pair list (the broad phase's result when no pair can be found)
_NO_PAIR = np.zeros(0, np.int64)

#: from this many candidate pairs of its own on, the convex phase runs as two calls at once, the second on the
#: machine's second core (:func:`cgp_core.second_core.beside`; issue 37): the first takes the ground and the first
#: part of the pair list, the second the rest, each pair's contacts found exactly as in one call, and the two
#: contact sets are joined in that order — the same :class:`ContactSet`, bit for bit, as one call gives.  A hull
#: pair takes ~4 µs here, and the split costs ~80 µs a sub-step (the thread's wake-up and hand-back, each call's
#: arguments unboxed in turn under the GIL, the join): it pays from ~45 pairs on.  Measured on the 100-hull pile at
#: rest (106 pairs, a free second core): the convex phase 2.13 -> 1.59-1.73 ms a tick.  Not for the narrow phase
#: of spheres, boxes and capsules (:func:`narrow_phase`): its pairs are cheap, and split it took longer (bench_rigid's
#: 200-body pile: 1.11 -> 1.33 ms a tick)
CONVEX_SPLIT_MIN_PAIRS = 64
#: what the ground's test of a hull costs beside a pair's, where the two calls' split is chosen (the first call takes
#: the ground: its contacts come first)
GROUND_PER_PAIR = 0.2

#: the stages of :attr:`CollisionDetector.profile`, in order
STAGES = ("bounds", "broad_phase", "narrow_phase", "convex_phase", "time_of_impact", "carry")
BOUNDS, BROAD_PHASE, NARROW_PHASE, CONVEX_PHASE, TIME_OF_IMPACT, CARRY = range(len(STAGES))


class _Detection(NamedTuple):
    """What a detection leaves for the sub-steps that carry its contacts (``world.contact_detection:
    once_per_tick``, :mod:`.carry`)."""

    model: BodyModel                        # the body model it was made for
    contacts: ContactSet | CarriedContacts  # its contacts; with their anchors once a sub-step has carried them
    sweep_pairs: tuple | None               # the fast-turn sweep's (moving, static, shape poses), or None
    position: np.ndarray                    # (n, 3) [m] the bodies' positions at the detection
    rotation: np.ndarray                    # (n, 3, 3) their rotations


class Pairs(NamedTuple):
    """Candidate primitive pairs (their AABBs overlap), ``q`` of them."""

    first: np.ndarray   # (q,) int64 primitive index
    second: np.ndarray  # (q,) int64 primitive index


class GroundPlane(NamedTuple):
    """The static ground z = 0 as the narrow phase takes it."""

    present: bool        # the scene has a ground
    friction: float      # its Coulomb μ
    restitution: float   # its coefficient of restitution e


class CollisionDetector:
    """Finds the contacts of a body model at the current state.

    Args:
        broad_phase: ``"sweep_and_prune"`` (default, compiled), ``"grid"`` or ``"brute_force"`` (see
            :mod:`.broadphase`), used above ``SMALL_SCENE`` primitives.
        speculative_distance: gap [m] below which contacts are always reported (see the module docstring).

    The collision primitives of a model are built on first use and cached, keyed on the model object (the
    model is static; a new model — bodies spawned or deleted — is a new object and gets new primitives).
    :attr:`profile` (a :class:`~cgp_core.jit.StageProfile`) accumulates the wall time of each stage
    (:data:`STAGES`) over the calls of :meth:`detect` until its ``reset()``.
    """

    def __init__(self, broad_phase: str = DEFAULT_BROAD_PHASE,
                 speculative_distance: float = DEFAULT_SPECULATIVE_DISTANCE, *, continuous: bool = True):
        self.broad_phase_name = broad_phase
        self.broad_phase = get_broad_phase(broad_phase)
        if not (isinstance(speculative_distance, (int, float)) and 0.0 <= speculative_distance < np.inf):
            raise ValueError(f"speculative_distance must be a finite length >= 0 [m], got {speculative_distance!r}")
        self.speculative_distance = float(speculative_distance)
        #: grow the margins by the motion over the sub-step and sweep fast-turning bodies (see the module
        #: docstring and :mod:`.convex_phase`); False only to show, in tests, what they prevent
        self.continuous = bool(continuous)
        self._model: BodyModel | None = None
        self._cmodel: CollisionModel | None = None
        self._plain_cmodel: tuple = ()  # the same as a plain tuple, as the compiled stages take it
        self._shapes: ShapeModel | None = None  # the convex stage's primitives (None: the model has none)
        self._plain_shapes: tuple = ()
        self._sweeps = None  # what sweep_fast_rotation needs from the last detect
        #: ``world.contact_detection: once_per_tick`` (:mod:`.carry`): whether a detection keeps its contacts to
        #: carry (World sets it for such a world), and whether the next :meth:`detect` carries them instead of
        #: detecting (World sets it for every sub-step but a tick's first)
        self.carrying = False
        self.carry_next = False
        #: how far [m] a body's surface may have moved since the contacts were detected before :meth:`detect`
        #: detects them again (:meth:`_moved`); None: :data:`CARRY_SHARE` of the speculative distance
        self.carry_tolerance: float | None = None
        #: the last detection's :class:`_Detection` while :attr:`carrying`, else None
        self._carried: _Detection | None = None
        #: the convex stage's BVH query scratch, kept from sub-step to sub-step (grown when a mesh pair needs it)
        self._candidates = np.empty(MESH_CANDIDATES, np.int64)
        self._candidates_beside = np.empty(MESH_CANDIDATES, np.int64)  # the second call's (CONVEX_SPLIT_MIN_PAIRS)
        self._extreme = np.zeros((0, 6), np.int64)  # (P, 6): tighten_hull_bounds' warm starts
        #: body pairs never tested (the robots' jointed links, :meth:`exclude`), or None
        self.excluded = None
        self._possible = None  # (model, excluded, whether a pair can be found): _pairs_possible's cache
        self._groups = None  # (primitive bodies, excluded, the broad phase's groups): _broad_groups' cache
        #: whether the last broad phase found the scene too dense for the sweep and ran the grid (the default
        #: broad phase only; see SWEEP_TESTS_PER_BOX)
        self.dense = False
        self._grid_calls_left = 0
        self.profile = StageProfile(STAGES)

    def collision_model(self, model: BodyModel) -> CollisionModel:
        if model is not self._model or self._cmodel is None or len(self._cmodel.body_reach) != model.count:
            self._cmodel = build_collision_model(model)
            self._plain_cmodel = tuple(self._cmodel)
            self._shapes = build_shape_model(model, self._cmodel) if model.has_convex_phase_shapes else None
            self._plain_shapes = self._shapes.plain() if self._shapes is not None else ()
            self._model = model
        return self._cmodel

    def shape_model(self, model: BodyModel) -> ShapeModel | None:
        """The primitives of the convex stage (:mod:`.convex_phase`), None for a model without its shapes."""
        self.collision_model(model)
        return self._shapes

    def detect(self, model: BodyModel, state: BodyState, h: float, *, ground: Ground | None,
               velocity: np.ndarray | None = None, angular_velocity: np.ndarray | None = None,
               rotation: np.ndarray | None = None, active: np.ndarray | None = None) -> ContactSet:
        """All contacts (touching, penetrating, or within the speculative margin) at ``state``'s poses.

        ``velocity`` / ``angular_velocity`` ``(n, 3)`` are the velocities the bodies will move with over the
        sub-step (default: the state's current ones); they only size the speculative margins.
        ``rotation`` ``(n, 3, 3)``: ``state.rotation_matrices()``, if the caller has it already.
        ``active`` ``(n,)`` bool: the bodies being stepped (default: every movable one).  Only pairs with an
        active body are tested; a sleeping movable body (movable, not active) is tested against the active ones
        and acts as static, and the contacts that touch one are reported in :attr:`touched_sleeping` (the
        caller wakes it: see :mod:`cgp_core.sleep`).
        """
        R = state.rotation_matrices() if rotation is None else rotation
        if self.carry_next and self._carried is not None and self._carried.model is model:
            start = time.perf_counter()
            if not self._moved(state.position, R):
                return self._carry(state, R, start)
            # a body moved: everything is detected again, as at a tick's first sub-step (detecting again only the
            # pairs of the bodies that moved, and sorting their new contacts in among the carried ones, cost more in
            # numpy than it saved while a pile piles: 100 hulls 19 % slower than detecting every sub-step)
        contacts = self._detect(model, state, h, ground, velocity, angular_velocity, R, active)
        self._carried = None
        if self.carrying:  # (the anchors only when a sub-step carries them: _anchored)
            sweeps = self._sweeps
            self._carried = _Detection(model, contacts, None if sweeps is None else (sweeps[1], sweeps[2], sweeps[5]),
                                       state.position.copy(), np.array(R))
        return contacts

    def _anchored(self) -> CarriedContacts:
        """The carried contacts with their anchors, computed at the first sub-step that carries them after a
        detection (at the poses of that detection)."""
        found = self._carried
        if isinstance(found.contacts, ContactSet):
            found = self._carried = found._replace(contacts=carry(found.contacts, found.position, found.rotation,
                                                                  self._cmodel.fixed_body))
        return found.contacts

    def _moved(self, position: np.ndarray, R: np.ndarray) -> bool:
        """Whether a movable body's surface may have moved since the contacts' detection by more than the carry
        tolerance (:attr:`carry_tolerance`): |Δx| + θ · reach, at the positions ``position (n, 3)`` and rotations
        ``R (n, 3, 3)`` now.  If none did, carrying them misses no contact: a detection's margins hold at least the
        speculative distance on each side (one for the ground), and two bodies that each moved by at most half of it
        closed their gap by less.  The turn matters as much as the shift: a hull turning about one point of its
        manifold brings other points of its surface to the other body, points the detection did not report
        (carrying every contact through the tick, margins sized for the whole tick, a hull tumbling onto another in
        the 100-hull pile sank 69 mm)."""
        X0, R0 = self._carried.position, self._carried.rotation  # (a fixed body's terms are zero)
        # cos θ = (trace(R R0ᵀ) − 1) / 2, and trace(R R0ᵀ) = Σᵢⱼ Rᵢⱼ R0ᵢⱼ
        cos_turn = 0.5 * (np.einsum("nij,nij->n", R, R0) - 1.0)
        reach = self._shapes.body_reach if self._shapes is not None else self._cmodel.body_reach
        shift = np.linalg.norm(position - X0, axis=1)
        tolerance = CARRY_SHARE * self.speculative_distance if self.carry_tolerance is None else self.carry_tolerance
        # (not ≤: a body whose state went non-finite within the tick counts as moved, and the detection that follows
        # leaves it out of every pair, as every sub-step's detection does, rather than carry NaN gaps to its partners)
        return not bool((shift + np.arccos(np.clip(cos_turn, -1.0, 1.0)) * reach <= tolerance).all())

    def _carry(self, state: BodyState, R: np.ndarray, start: float) -> ContactSet:
        """The last detection's contacts carried to the poses of ``state`` (rotations ``R``: :mod:`.carry`), and
        the fast-turn sweep (:meth:`sweep_fast_rotation`) armed again for the pairs it found; timed from ``start``
        (the clock when :meth:`detect` began: the motion check is the ``carry`` stage's too)."""
        carried = self._anchored()
        model, sweep_pairs = self._carried.model, self._carried.sweep_pairs
        self.touched_sleeping = np.zeros(0, np.intp)
        self._sweeps = None if sweep_pairs is None else (model, sweep_pairs[0], sweep_pairs[1], state.position.copy(),
                                                          np.array(R), sweep_pairs[2])
        contacts = carried_contacts(carried, state.position, R)
        self.profile.add(CARRY, time.perf_counter() - start)
        return contacts

    def _detect(self, model, state, h, ground, velocity, angular_velocity, rotation, active) -> ContactSet:
        """:meth:`detect`'s detection, margins sized for ``h`` seconds of motion."""
        cm = self.collision_model(model)
        self.touched_sleeping = np.zeros(0, np.intp)
        self._sweeps = None
        if cm.count == 0 and self._shapes is None:
            return ContactSet.empty()
        if ground is None and not self._pairs_possible():
            # nothing to detect: no ground, and every pair of bodies the broad phase could find is excluded (a lone
            # robot without self-collision and nothing else) — the stages below would find no contact
            self.profile.calls += 1
            return ContactSet.empty()
        if velocity is None:
            velocity = state.linear_velocity(model)
        if angular_velocity is None:
            angular_velocity = state.angular_velocity(model)
        R = state.rotation_matrices() if rotation is None else rotation
        movable = ~cm.fixed_body
        active = movable if active is None else active & movable
        h_motion = float(h) if self.continuous else 0.0  # (only the margins: h (|v| + |ω| reach))
        clock, profile = time.perf_counter, self.profile
        start = clock()
        motion = (state.position, np.ascontiguousarray(R), velocity, angular_velocity)  # a BodyMotion
        poses = primitive_bounds(self._plain_cmodel, motion, h_motion, self.speculative_distance)
        # a primitive whose body's state went non-finite (a numerical blow-up, which World contains after the
        # tick) takes no part in collisions rather than stopping everyone else's step: its bounds are NaN (see
        # primitive_bounds), so no overlap test passes
        if self._shapes is not None:
            return self._detect_with_shapes(model, motion, poses, active, ground, h_motion, start)
        lo, hi = poses.lo, poses.hi
        now = clock()
        profile.add(BOUNDS, now - start)
        start = now
        i, j = self._candidate_pairs(lo, hi, cm.body, active)
        now = clock()
        profile.add(BROAD_PHASE, now - start)
        start = now
        ground_plane = (True, ground.friction, ground.restitution) if ground is not None else (False, 0.0, 0.0)
        contacts, touched = narrow_phase(self._plain_cmodel, tuple(poses), (i, j), active, ground_plane)
        profile.add(NARROW_PHASE, clock() - start)
        profile.calls += 1
        if touched.any():
            self.touched_sleeping = np.flatnonzero(touched)
        return contacts

    def exclude(self, group: np.ndarray, jointed: np.ndarray, self_collision: np.ndarray) -> None:
        """Body pairs the narrow phase never tests (what :class:`cgp_core.robots.world.Robots` would drop anyway):
        two bodies of one group ``group (n,)`` (−1: none), unless the group has ``self_collision (g,)`` and they are
        not jointed (``jointed (n,)``: the body each is jointed to, −1: none).  A robot's links overlap their
        parents' at every joint: their hulls' GJK / EPA would be most of a robot's detection time."""
        self.excluded = (np.asarray(group, np.int64), np.asarray(jointed, np.int64), np.asarray(self_collision, bool))
        self._possible = None

    def _pairs_possible(self) -> bool:
        """Whether the broad phase could find a pair that is not excluded (conservative: True unless sure), for the
        current collision model and :attr:`excluded`: False when the bodies with a primitive are all fixed, or all
        of one group without self-collision (:meth:`exclude`), or fewer than two.  Cached until either changes."""
        key = (self._model, self.excluded)
        cached = self._possible
        if cached is not None and cached[0] is key[0] and cached[1] is key[1]:
            return cached[2]
        body = self._shapes.primitives.body if self._shapes is not None else self._cmodel.body
        bodies = np.unique(body)
        fixed = self._cmodel.fixed_body
        possible = bool(len(bodies) >= 2 and (~fixed[bodies]).any())
        if possible and self.excluded is not None:
            group, _, self_collision = self.excluded
            if len(group) > int(bodies.max()):
                g = group[bodies]
                one = int(g[0])
                if one >= 0 and (g == one).all() and not self_collision[one]:
                    possible = False  # every pair is two bodies of one group without self-collision: all excluded
        self._possible = (key[0], key[1], possible)
        return possible

    def _drop_excluded(self, i, j, prim_body):
        group, jointed, self_collision = self.excluded
        if not len(i) or len(group) <= int(prim_body.max(initial=-1)):
            return i, j
        a, b = prim_body[i], prim_body[j]
        ga = group[a]
        drop = (ga >= 0) & (ga == group[b])
        if drop.any():
            drop &= ~self_collision[np.maximum(ga, 0)] | (jointed[a] == b) | (jointed[b] == a)
            keep = ~drop
            i, j = np.ascontiguousarray(i[keep]), np.ascontiguousarray(j[keep])
        return i, j

    def _candidate_pairs(self, lo, hi, prim_body, active):
        """The broad phase: primitive pairs ``i, j`` whose AABBs overlap (less those :meth:`exclude` names)."""
        if not self._pairs_possible():  # every pair would be excluded: none to look for
            return _NO_PAIR, _NO_PAIR
        i, j = self._broad_pairs(lo, hi, prim_body, active)
        if self.excluded is not None:
            i, j = self._drop_excluded(i, j, prim_body)
        return i, j

    def _broad_groups(self, prim_body):
        """The broad phase's group of each primitive (it pairs no two of one group): its body, or one group for all
        the bodies of an :meth:`exclude` group without self-collision (every pair of them excluded), so that the
        sweep skips a robot's links among themselves rather than find every pair of them to drop it.  Cached for
        ``prim_body`` and :attr:`excluded`."""
        cached = self._groups
        if cached is not None and cached[0] is prim_body and cached[1] is self.excluded:
            return cached[2]
        groups = prim_body
        if self.excluded is not None:
            group, _, self_collision = self.excluded
            n = len(group)
            if len(prim_body) and n > int(prim_body.max()):
                merged = (group >= 0) & ~self_collision[np.maximum(group, 0)]
                body_group = np.where(merged, n + group, np.arange(n))
                groups = np.ascontiguousarray(body_group[prim_body], np.int64)
        self._groups = (prim_body, self.excluded, groups)
        return groups

    def _broad_pairs(self, lo, hi, prim_body, active):
        """The broad phase: primitive pairs ``i, j`` whose AABBs overlap."""
        count = len(lo)
        if count <= SMALL_SCENE:
            return small_scene_pairs(lo, hi, prim_body, active)
        prim_body = self._broad_groups(prim_body)  # (the sweep's, the grid's and the others' groups)
        if self.broad_phase is sweep_and_prune_pairs:
            # one compiled call, no same-body pair; the order of the pairs does not matter here.  A scene too
            # dense for the sweep goes to the grid (SWEEP_TESTS_PER_BOX) for GRID_CALLS calls
            if self._grid_calls_left == 0:
                i, j, complete = sweep_and_prune_kernel(lo, hi, prim_body, SWEEP_TESTS_PER_BOX * count)
                if complete:
                    self.dense = False
                    return i, j
                self._grid_calls_left = GRID_CALLS
            self._grid_calls_left -= 1
            self.dense = True
            return grid_kernel(lo, hi, prim_body, 0.0)
        sane = np.flatnonzero(np.isfinite(lo).all(1) & np.isfinite(hi).all(1))
        if sane.size == count:
            i, j = self.broad_phase(lo, hi, group=prim_body)
        else:
            i, j = self.broad_phase(lo[sane], hi[sane], group=prim_body[sane])
            i, j = sane[i], sane[j]
        return np.ascontiguousarray(i, np.int64), np.ascontiguousarray(j, np.int64)

    def _detect_with_shapes(self, model: BodyModel, motion: tuple, poses: PrimitivePoses, active: np.ndarray,
                            ground: Ground | None, h_motion: float, start: float) -> ContactSet:
        """:meth:`detect` for a model with convex hulls, compound bodies or static meshes (stages 1–4 of the
        module docstring), from the detector's own :class:`PrimitivePoses` on; ``start``: the clock at the
        ``bounds`` stage's start."""
        clock, profile = time.perf_counter, self.profile
        cm, shapes = self._cmodel, self._shapes
        p, P = cm.count, shapes.count
        every = ShapePoses(np.empty((P, 3)), np.empty((P, 3, 3)), np.empty((P, 3)), np.empty((P, 3)), np.empty(P))
        every.centre[:p], every.lo[:p], every.hi[:p], every.margin[:p] = poses.centre, poses.lo, poses.hi, poses.margin
        pose_shapes(self._plain_shapes, motion, h_motion, self.speculative_distance, tuple(every))
        now = clock()
        profile.add(BOUNDS, now - start)
        start = now
        i, j = self._candidate_pairs(every.lo, every.hi, shapes.primitives.body, active)
        # the hulls' exact bounds where a pair or the ground is near (pose_shapes bounds them by their turned local
        # boxes): the pairs and ground tests of exact bounds, each hull's vertices turned only there
        prims = shapes.primitives
        if len(self._extreme) != P:  # each hull's extreme vertices per direction, where the bounds' search starts
            self._extreme = np.zeros((P, 6), np.int64)
        i, j = tighten_hull_bounds(prims.kind, prims.hull, self._plain_shapes[1], prims.first_new, tuple(every), i, j,
                                   ground is not None, self._extreme)
        now = clock()
        profile.add(BROAD_PHASE, now - start)
        start = now
        ground_plane = (True, ground.friction, ground.restitution) if ground is not None else (False, 0.0, 0.0)
        parts = []
        touched = np.zeros(model.count, bool)
        if p:
            old = (i < p) & (j < p)
            contacts, touched_old = narrow_phase(self._plain_cmodel, tuple(poses),
                                                 (np.ascontiguousarray(i[old]), np.ascontiguousarray(j[old])),
                                                 active, ground_plane)
            parts.append(contacts)
            touched |= touched_old
        now = clock()
        profile.add(NARROW_PHASE, now - start)
        start = now
        contacts, touched_new = self._convex_contacts(every, i, j, active, ground_plane, np.int64((p + 1) ** 2))
        parts.append(contacts)
        touched |= touched_new
        if self.continuous:
            moving, static = fast_turn_pairs(self._plain_shapes, active, motion[3], h_motion, (i, j))
            if len(moving):
                self._sweeps = (model, moving, static, motion[0].copy(), motion[1].copy(), every)
        profile.add(CONVEX_PHASE, clock() - start)
        profile.calls += 1
        if touched.any():
            self.touched_sleeping = np.flatnonzero(touched)
        return ContactSet.concatenate(parts)

    def _convex_contacts(self, named: ShapePoses, i: np.ndarray, j: np.ndarray, active: np.ndarray,
                         ground_plane: tuple, key_base: np.int64) -> tuple[ContactSet, np.ndarray]:
        """:func:`.convex_phase.convex_phase` of the pairs ``i, j`` (those of two narrow-phase primitives skipped in
        it): one call, or from :data:`CONVEX_SPLIT_MIN_PAIRS` pairs of its own on two at once, each with a BVH
        query scratch of its own."""
        shapes, first_new, poses = self._plain_shapes, self._shapes.primitives.first_new, tuple(named)
        own = np.flatnonzero((i >= first_new) | (j >= first_new)) if len(i) >= CONVEX_SPLIT_MIN_PAIRS else _NO_PAIR
        if len(own) < CONVEX_SPLIT_MIN_PAIRS or not second_core.available():
            contacts, touched, self._candidates = convex_phase(shapes, poses, (i, j), active, ground_plane, key_base,
                                                               self._candidates, self._extreme)
            return contacts, touched
        near = int(np.count_nonzero(named.lo[first_new:, 2] < named.margin[first_new:])) if ground_plane[0] else 0
        half = _cut(len(own), near)  # of its own pairs; the others are skipped in either call
        cut = int(own[half]) if half < len(own) else len(i)
        no_ground = (False, *ground_plane[1:])  # (the types of ground_plane's: no second signature to compile)
        later = second_core.beside(convex_phase, shapes, poses, (i[cut:], j[cut:]), active, no_ground, key_base,
                                   self._candidates_beside, self._extreme)
        try:
            first = convex_phase(shapes, poses, (i[:cut], j[:cut]), active, ground_plane, key_base, self._candidates,
                                 self._extreme)
        finally:
            second = later.result()
        self._candidates, self._candidates_beside = first[2], second[2]
        return ContactSet.concatenate([first[0], second[0]]), first[1] | second[1]

    def sweep_fast_rotation(self, model: BodyModel, state: BodyState, h: float) -> None:
        """Continuous collision for fast rotation (pipeline stage 4, right after the integrator; see
        :mod:`.convex_phase`), timed as the ``time_of_impact`` stage: every body that the last :meth:`detect` found
        turning by more than :data:`.convex_phase.TOI_ANGLE` next to a fixed hull, box or mesh is swept from its
        pose then to its pose now (constant velocity and angular velocity, :func:`.convex_phase.sweep_times`:
        conservative advancement); if it touched within the sub-step it is put back at its pose at that time of
        impact.  Its momenta are kept: the next sub-step's contact, made at that pose, stops it.  A no-op when
        nothing turned that fast."""
        sweeps, self._sweeps = self._sweeps, None
        if sweeps is None or sweeps[0] is not model or self._shapes is None:
            return
        from ..rotation import matrix_to_quat, quat_from_rotvec, quat_multiply, quat_to_rotvec
        from .toi import rotated

        start = time.perf_counter()
        _, moving, static, position0, rotation0, poses = sweeps
        prims = self._shapes.primitives
        bodies = np.unique(prims.body[moving])
        R1 = state.rotation_matrices()
        velocity = np.zeros((model.count, 3))
        angular_velocity = np.zeros((model.count, 3))
        velocity[bodies] = (state.position[bodies] - position0[bodies]) / h
        turn = matrix_to_quat(R1[bodies] @ np.swapaxes(rotation0[bodies], -1, -2))  # R1 R0ᵀ
        angular_velocity[bodies] = quat_to_rotvec(turn) / h
        times = sweep_times(self._plain_shapes, moving, static, tuple(poses),
                            (position0, rotation0, velocity, angular_velocity), float(h), TOI_TARGET, TOI_TOLERANCE)
        first = np.ones(model.count)
        np.minimum.at(first, prims.body[moving], times)
        for b in np.flatnonzero(first < 1.0):
            t = first[b]
            state.position[b] = position0[b] + velocity[b] * h * t
            R = rotated(rotation0[b], *angular_velocity[b], h * t)
            q0 = matrix_to_quat(rotation0[b][None])[0]
            q = quat_multiply(quat_from_rotvec(angular_velocity[b] * h * t), q0)
            state.orientation[b] = q / np.linalg.norm(q)
            if state.rotation is not None:
                state.rotation[b] = R
        self.profile.add(TIME_OF_IMPACT, time.perf_counter() - start)


@njit
def small_scene_pairs(lo, hi, prim_body, active):
    """Every overlapping pair ``i < j`` of AABBs of different bodies, at least one of them active, in (i, j)
    order: the broad phase for a handful of primitives, where building any structure costs more."""
    p = len(lo)
    count = 0
    pi = np.empty(p * (p - 1) // 2 + 1, np.int64)
    pj = np.empty(p * (p - 1) // 2 + 1, np.int64)
    for i in range(p):
        for j in range(i + 1, p):
            if prim_body[i] == prim_body[j] or not (active[prim_body[i]] or active[prim_body[j]]):
                continue
            if lo[i, 0] <= hi[j, 0] and lo[j, 0] <= hi[i, 0] and lo[i, 1] <= hi[j, 1] and lo[j, 1] <= hi[i, 1] \
                    and lo[i, 2] <= hi[j, 2] and lo[j, 2] <= hi[i, 2]:
                pi[count] = i
                pj[count] = j
                count += 1
    return pi[:count], pj[:count]


def _cut(pairs: int, near_ground: int) -> int:
    """Where the convex phase's list of ``pairs`` pairs is cut in two for :func:`cgp_core.second_core.beside`: the
    first call takes the ground's tests of ``near_ground`` hulls too (:data:`GROUND_PER_PAIR` of a pair's cost
    each), so about half the work on either side."""
    return int(min(max((pairs - GROUND_PER_PAIR * near_ground) // 2, 0), pairs))


@njit
def narrow_phase(primitives, poses, pairs, active, ground):
    """Contact points of the active primitives with the ground and of the candidate pairs: the
    :class:`ContactSet` (ground contacts first, in primitive order, then the pairs in the order given), and
    ``touched (n,)`` bool: the sleeping bodies (movable, not ``active``) in a contact.  A pair's side A is the
    primitive whose shape comes first in SPHERE < BOX < CAPSULE.  Materials: friction √(μ_a μ_b), restitution
    max(e_a, e_b) (see :mod:`.materials`).

    ``primitives``: :class:`CollisionModel`; ``poses``: :class:`PrimitivePoses`; ``pairs``: :class:`Pairs`;
    ``active`` (n,) bool: the bodies being stepped; ``ground``: :class:`GroundPlane` — bundles as plain tuples
    from Python (see :mod:`cgp_core.jit`)."""
    primitives, poses, pairs, ground = (CollisionModel(*primitives), PrimitivePoses(*poses), Pairs(*pairs),
                                        GroundPlane(*ground))
    prim_body = primitives.body
    p = len(prim_body)
    cap = MAX_POINTS_PER_PAIR * (p + len(pairs.first)) + 1
    out = ContactBuffer(np.empty((cap, 3)), np.empty(cap), np.empty((cap, 3)), np.empty(cap, np.int64))
    prim_a = np.empty(cap, np.int64)  # −1: the ground
    prim_b = np.empty(cap, np.int64)
    axes = np.empty((2, 3))  # capsule axes (the columns 2 of their rotations)
    # (an int64, not a literal 0: numba would also compile the kernels it is passed to for a literal 0)
    m = np.int64(0)

    # -- the ground plane z = 0 (side A) against every active primitive near it
    if ground.present:
        for k in range(p):
            if not active[prim_body[k]] or not poses.lo[k, 2] < poses.margin[k]:
                continue
            start = m
            m = _ground_contacts(k, primitives, poses, axes[1], out, m)
            prim_a[start:m] = -1
            prim_b[start:m] = k

    # -- primitive pairs
    for q in range(len(pairs.first)):
        i, j = pairs.first[q], pairs.second[q]
        bi, bj = prim_body[i], prim_body[j]
        if bi == bj or not (active[bi] or active[bj]):
            continue
        a, b = (j, i) if primitives.shape[i] > primitives.shape[j] else (i, j)
        start = m
        m = _pair_contacts(a, b, primitives, poses, axes, out, m)
        prim_a[start:m] = a
        prim_b[start:m] = b
    return _contact_set(primitives, out, prim_a, prim_b, m, active, ground)


@njit(inline="always")
def _ground_contacts(k, primitives, poses, axis, out, m):
    """The ground (A) against primitive ``k`` (B), written into ``out`` from row ``m``; returns the next free row.
    ``axis`` (3,): work space."""
    shape, centre, margin = primitives.shape[k], poses.centre[k], poses.margin[k]
    R = poses.rotation[primitives.body[k]]
    if shape == SPHERE:
        nx, ny, nz, s, px, py, pz = sphere_plane_point(centre, primitives.radius[k])
        if s < margin:
            m = write_point(out, m, nx, ny, nz, s, px, py, pz, 0)
    elif shape == BOX:
        m = box_plane_contacts(Box(centre, R, primitives.half_extents[k]), margin, out, m)
    else:
        _column(R, 2, axis)
        m = capsule_plane_contacts(Capsule(centre, axis, primitives.half_extents[k, 2], primitives.radius[k]),
                                   margin, out, m)
    return m


@njit(inline="always")
def _pair_contacts(a, b, primitives, poses, axes, out, m):
    """Primitive ``a`` (A) against primitive ``b`` (B), shapes in SPHERE < BOX < CAPSULE order, written into
    ``out`` from row ``m``; returns the next free row.  ``axes`` (2, 3): work space."""
    sa, sb = primitives.shape[a], primitives.shape[b]
    centre, radius, half = poses.centre, primitives.radius, primitives.half_extents
    Ra, Rb = poses.rotation[primitives.body[a]], poses.rotation[primitives.body[b]]
    limit = poses.margin[a] + poses.margin[b]
    axis_a, axis_b = axes[0], axes[1]
    if sa == SPHERE and sb != BOX and sb != CAPSULE:
        nx, ny, nz, s, px, py, pz = sphere_sphere_point(centre[a, 0], centre[a, 1], centre[a, 2], radius[a],
                                                        centre[b, 0], centre[b, 1], centre[b, 2], radius[b])
        if s < limit:
            m = write_point(out, m, nx, ny, nz, s, px, py, pz, 0)
    elif sa == SPHERE and sb == BOX:
        nx, ny, nz, s, px, py, pz = sphere_box_point(centre[a], radius[a], Box(centre[b], Rb, half[b]))
        if s < limit:
            m = write_point(out, m, nx, ny, nz, s, px, py, pz, 0)
    elif sa == SPHERE:
        _column(Rb, 2, axis_b)
        nx, ny, nz, s, px, py, pz = sphere_capsule_point(centre[a], radius[a],
                                                         Capsule(centre[b], axis_b, half[b, 2], radius[b]))
        if s < limit:
            m = write_point(out, m, nx, ny, nz, s, px, py, pz, 0)
    elif sa == BOX and sb == BOX:
        m = box_box_contacts(Box(centre[a], Ra, half[a]), Box(centre[b], Rb, half[b]), limit, out, m)
    elif sa == BOX:
        _column(Rb, 2, axis_b)
        m = box_capsule_contacts(Box(centre[a], Ra, half[a]), Capsule(centre[b], axis_b, half[b, 2], radius[b]),
                                 limit, out, m)
    else:
        _column(Ra, 2, axis_a)
        _column(Rb, 2, axis_b)
        m = capsule_capsule_contacts(Capsule(centre[a], axis_a, half[a, 2], radius[a]),
                                     Capsule(centre[b], axis_b, half[b, 2], radius[b]), limit, out, m)
    return m


@njit
def _contact_set(primitives, out, prim_a, prim_b, m, active, ground):
    """The :class:`ContactSet` of the ``m`` points in ``out`` (of primitives ``prim_a``, ``prim_b``: bodies,
    identity keys, materials), and ``touched (n,)``: the sleeping (movable, not active) bodies touched."""
    prim_body, body_friction, body_restitution = primitives.body, primitives.body_friction, primitives.body_restitution
    p = len(prim_body)
    touched = np.zeros(len(active), np.bool_)
    body_a = np.empty(m, np.int64)
    body_b = np.empty(m, np.int64)
    key = np.empty(m, np.int64)
    friction = np.empty(m)
    restitution = np.empty(m)
    for c in range(m):
        body_b[c] = prim_body[prim_b[c]]
        if prim_a[c] < 0:
            body_a[c] = GROUND
            mu_a, e_a = ground.friction, ground.restitution
        else:
            body_a[c] = prim_body[prim_a[c]]
            mu_a, e_a = body_friction[body_a[c]], body_restitution[body_a[c]]
        friction[c] = combine_friction(mu_a, body_friction[body_b[c]])
        restitution[c] = combine_restitution(e_a, body_restitution[body_b[c]])
        key[c] = contact_key(prim_a[c], prim_b[c], out.feature[c], p)
        for body in (body_a[c], body_b[c]):
            if body >= 0 and not primitives.fixed_body[body] and not active[body]:
                touched[body] = True
    contacts = ContactSet(body_a, body_b, out.normal[:m].copy(), out.separation[:m].copy(), out.point[:m].copy(),
                          key, friction, restitution)
    return contacts, touched


@njit
def contact_key(prim_a, prim_b, feature, primitive_count):
    """Contact identity: (primitive A + 1, primitive B, feature) packed into one int64 (A = −1: the ground)."""
    return ((prim_a + 1) * (primitive_count + 1) + prim_b) * FEATURE_SLOTS + feature


@njit
def _column(R, k, out):
    out[0] = R[0, k]
    out[1] = R[1, k]
    out[2] = R[2, k]
