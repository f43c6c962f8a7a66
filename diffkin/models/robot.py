"""Whole robots: kinematic trees with named frames, mimic (coupled) joints and floating bases.

A :class:`Robot` is a tree of rigid *bodies* joined by moving joints. Body ``0`` is the root;
joint ``j`` moves body ``j + 1`` relative to body ``parents[j]`` (so parents come first):

    T_world_body[j + 1] = T_world_body[parents[j]] @ joint_poses[j] @ exp([screws[j]] theta_j)
    theta_j = multipliers[j] * q[sources[j]] + offsets[j]

Fixed joints are merged: a link fixed to a body is a named *frame* of that body, at a constant
pose ``frame_poses[f]`` in the body frame. URDF links and MJCF bodies and sites are all frames.
``q`` holds the actuated joints only; a mimic joint follows its source joint through
``multipliers``/``offsets`` (and an MJCF joint's ``ref`` is an offset too). Each body has a mass
and a centre of mass (its links' URDF ``<inertial>`` or MJCF inertial, merged over fixed joints).

Robots are built by the loaders (:func:`diffkin.load_robot`) through
:func:`diffkin.models._tree.build`.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from diffkin import _rigid as rg
from diffkin import _validate as check
from diffkin import _xla
from diffkin._pytree import pytree_dataclass, static
from diffkin._static import host, is_concrete
from diffkin.models import _ball, _levels, _loops, _scanned
from diffkin.models._passes import RobotPass
from diffkin.models.poe import PoEChain, _screw_types


@pytree_dataclass
class Robot:
    """A kinematic tree (see the module docstring for the forward pass).

    Attributes:
        joint_poses: ``(nj, 4, 4)`` pose of each moving joint's frame in its parent body's frame
            at ``theta = 0``.
        screws: ``(nj, 6)`` unit screw ``[v; w]`` of each joint in its own frame: revolute
            ``[c x w; w]`` (rotation about the axis ``w`` through the point ``c``), prismatic ``[v; 0]``.
        multipliers, offsets: ``(nj,)``: ``theta_j = multipliers[j] * q[sources[j]] + offsets[j]``
            (``1, 0`` for an actuated joint without MJCF ``ref``).
        frame_poses: ``(nf, 4, 4)`` pose of each named frame in the frame of its body.
        lower, upper: ``(dof,)`` limits of the actuated joints (``-inf``/``inf`` if unlimited).
        masses: ``(nj + 1,)`` mass of each body in kg (its links merged).
        body_coms: ``(nj + 1, 3)`` centre of mass of each body in the body's frame (metres).
        parents: static, per joint, the index of its parent body (``< j + 1``).
        joint_types: static, per joint, ``"R"`` (revolute), ``"P"`` (prismatic) or ``"B"`` (one of a
            ball joint's three: :mod:`diffkin.models._ball`).
        sources: static, per joint, the index in ``q`` of the actuated joint that drives it.
        tree_joints: static, per joint, its name (mimic joints included).
        frame_bodies: static, per frame, the index of its body.
        frame_names: static, per frame, its name: every link (or MJCF body), then extra frames.
        joint_names: static names of the actuated joints, the order of ``q``.
        floating: static; ``True`` if the root moves (its pose is an argument of ``fk``).
        name: static name of the robot.
        unknown_masses: static, the links whose mass the file does not determine (an MJCF mesh
            geom without ``<inertial>``), each with the reason; :func:`diffkin.com` refuses them.
        loop_points: ``(nl, 2, 3)`` per closed loop, a point in each of its two bodies that must
            coincide (:mod:`diffkin.models._loops`); ``loop_bodies``: static, the two bodies.
        dependent_home: ``(nd,)`` reference values of the dependent joints (solved from ``q``, not in
            it: ``sources`` index ``dof + d``); ``dependent_names``: static, their names.
        velocity: ``(dof,)`` velocity limits of the actuated joints, ``|dq/dt| <= velocity`` (rad/s,
            m/s; ``inf``: none), the default of :func:`diffkin.ik.step`: a URDF's ``<limit velocity=>``
            (0 or absent: none); MJCF has none (MuJoCo limits positions, forces and controls, not joint
            velocities). As with ``lower``/``upper``, a mimic joint's own limit is not read (its source's
            holds). The last field; built without it: ``inf`` per joint.
    """

    joint_poses: jax.Array
    screws: jax.Array
    multipliers: jax.Array
    offsets: jax.Array
    frame_poses: jax.Array
    lower: jax.Array
    upper: jax.Array
    masses: jax.Array
    body_coms: jax.Array
    loop_points: jax.Array
    dependent_home: jax.Array
    parents: tuple[int, ...] = static()
    joint_types: str = static()
    sources: tuple[int, ...] = static()
    tree_joints: tuple[str, ...] = static()
    frame_bodies: tuple[int, ...] = static()
    frame_names: tuple[str, ...] = static()
    joint_names: tuple[str, ...] = static()
    floating: bool = static(default=False)
    name: str = static(default="")
    unknown_masses: tuple[str, ...] = static(default=())
    loop_bodies: tuple[tuple[int, int], ...] = static(default=())
    dependent_names: tuple[str, ...] = static(default=())
    velocity: jax.Array = None  # type: ignore[assignment]  # filled: check.no_velocity_limits

    def _fill(self) -> dict:
        return check.no_velocity_limits(self)

    @property
    def dof(self) -> int:
        return len(self.joint_names)

    def _check(self, concrete: bool) -> None:
        """Static structure and leaf shapes always; values (unit screws, rigid poses, limits) when concrete."""
        nj, nf, dof = len(self.tree_joints), len(self.frame_names), len(self.joint_names)
        for name, value, size in (
            ("parents", self.parents, nj),
            ("sources", self.sources, nj),
            ("frame_bodies", self.frame_bodies, nf),
        ):
            if not isinstance(value, tuple) or len(value) != size or not all(isinstance(i, int) for i in value):
                raise TypeError(f"{name}: expected a tuple of {size} ints, got {value!r}")
        if not isinstance(self.joint_types, str) or len(self.joint_types) != nj or set(self.joint_types) - set("RPB"):
            raise ValueError(f"joint_types: expected {nj} letters 'R'/'P'/'B', got {self.joint_types!r}")
        for j, parent in enumerate(self.parents):
            if not 0 <= parent <= j:
                raise ValueError(f"parents[{j}]: expected a body in [0, {j}] (parents come first), got {parent}")
        nd, nl = len(self.dependent_names), len(self.loop_bodies)
        if any(not 0 <= i < dof + nd for i in self.sources) or any(not 0 <= b <= nj for b in self.frame_bodies):
            raise ValueError(
                f"sources/frame_bodies: expected indices of q and its dependents (< {dof + nd}) and of bodies (<= {nj})"
            )
        if any(
            len(pair) != 2 or not all(isinstance(b, int) and 0 <= b <= nj for b in pair) for pair in self.loop_bodies
        ):
            raise ValueError(f"loop_bodies: expected pairs of body indices (<= {nj}), got {self.loop_bodies!r}")
        check.leaf(self.loop_points, "loop_points", (nl, 2, 3), concrete)
        check.leaf(self.dependent_home, "dependent_home", (nd,), concrete)
        _ball.check_structure(self.joint_types, self.parents, self.sources)
        for name, names in (
            ("frame_names", self.frame_names),
            ("joint_names", self.joint_names),
            ("tree_joints", self.tree_joints),
            ("dependent_names", self.dependent_names),
        ):
            if len(set(names)) != len(names) or not all(isinstance(n, str) for n in names):
                raise ValueError(f"{name}: expected distinct strings, got {names!r}")
        check.flag(self.floating, "floating")
        check.text(self.name, "name")
        P = check.leaf(self.joint_poses, "joint_poses", (nj, 4, 4), concrete)
        S = check.leaf(self.screws, "screws", (nj, 6), concrete)
        check.leaf(self.multipliers, "multipliers", (nj,), concrete)
        check.leaf(self.offsets, "offsets", (nj,), concrete)
        F = check.leaf(self.frame_poses, "frame_poses", (nf, 4, 4), concrete)
        lo, hi = check.limit_leaves(self, dof, concrete)
        check.velocity_leaf(self, dof, concrete)
        m = check.leaf(self.masses, "masses", (nj + 1,), concrete)
        check.leaf(self.body_coms, "body_coms", (nj + 1, 3), concrete)
        if not isinstance(self.unknown_masses, tuple) or not all(isinstance(n, str) for n in self.unknown_masses):
            raise TypeError(f"unknown_masses: expected a tuple of strings, got {self.unknown_masses!r}")
        if not concrete:
            return
        assert m is not None
        if np.any(m < 0):
            raise ValueError(f"masses: expected non-negative masses (kg), got {m.min()} at index {int(m.argmin())}")
        assert S is not None and P is not None and F is not None  # concrete: check.leaf returned the values
        tol = check.tolerance(self.screws)
        for j, kind in enumerate(_screw_types(S, tol)):
            if kind != self.joint_types[j].replace("B", "R"):
                raise ValueError(f"joint_types[{j}]: {self.joint_types[j]!r} contradicts screws[{j}] ({kind!r})")
        for j in _ball.starts(self.joint_types):
            _ball.check_values(j, P, S, np.asarray(self.multipliers), np.asarray(self.offsets), tol)
        for name, poses, leaf in (("joint_poses", P, self.joint_poses), ("frame_poses", F, self.frame_poses)):
            for i, T in enumerate(poses):
                check.rigid_transform(T, f"{name}[{i}]", tol=check.tolerance(leaf))
        check.limits(lo, hi, dof)

    @property
    def actuated_types(self) -> str:
        """``"R"``/``"P"``/``"B"`` (ball: :mod:`diffkin.models._ball`) of each entry of ``q``
        (:attr:`joint_types` is per tree joint)."""
        kinds = {name: kind for name, kind in zip(self.tree_joints, self.joint_types, strict=True)}
        return "".join(kinds[name] for name in self.joint_names)

    @property
    def scanned(self) -> bool:
        """Whether :meth:`forward` is the scanned pass (a path of more than :data:`~diffkin.models._scanned.LONG`
        joints)."""
        return _scanned.longest_path(self.parents) > _scanned.LONG

    @property
    def mimic(self) -> dict[str, tuple[str, float, float]]:
        """``{joint: (source, multiplier, offset)}`` of the joints that follow another (host values)."""
        m, o = np.asarray(self.multipliers, np.float64), np.asarray(self.offsets, np.float64)
        return {
            name: (self.joint_names[s], float(m[j]), float(o[j]))
            for j, (name, s) in enumerate(zip(self.tree_joints, self.sources, strict=True))
            if s < self.dof and name != self.joint_names[s]
        }

    def frame_index(self, name: str) -> int:
        """Index of the frame ``name`` in :attr:`frame_names`; a ValueError names the closest frames."""
        if not isinstance(name, str):
            raise TypeError(f"frame name: expected a string, got {type(name).__name__}")
        try:
            return self.frame_names.index(name)
        except ValueError:
            import difflib  # only on this error path

            names = self.frame_names
            similar = difflib.get_close_matches(name, names, n=5, cutoff=0.6)
            containing = [n for n in names if name.lower() in n.lower()]
            close = list(dict.fromkeys(similar + containing))[:5]
            hint = (
                f"the closest names are {', '.join(map(repr, close))}"
                if close
                else f"none named like it (the first: {', '.join(map(repr, names[:3]))}, ...)"
            )
            raise ValueError(f"unknown frame {name!r}: the robot has {len(names)} frames, {hint}") from None

    def ancestors(self, body: int) -> list[int]:
        """The joints between the root and ``body``, root first."""
        path = []
        while body > 0:
            path.append(body - 1)
            body = self.parents[body - 1]
        return path[::-1]

    def forward(self, q: Sequence[rg.Entry], base: rg.Rigid = rg.IDENTITY) -> RobotPass:
        """The forward pass (:mod:`diffkin.models.forward`): every body's pose and every joint's screw.

        Args:
            q: ``dof`` joint values (arrays of any batch shape, or Python floats).
            base: ``T_world_root``.
        """
        if not self.loop_bodies:
            return self.tree_pass(q, base)
        dependent, fold = _loops.solve(self, list(q))
        kin = self.tree_pass(list(q) + dependent, base)
        kin.dependent, kin.fold, kin.loop_gap = dependent, fold, _loops.gap(self, kin)  # on these very poses
        return kin

    @property
    def by_depth(self) -> bool:
        """Whether :meth:`forward_by_depth` takes the robot: a tree of one-axis joints (no ball joint, no closed
        loop, no path of more than :data:`~diffkin.models._scanned.LONG` joints) with concrete numbers, each
        revolute about an axis through its frame's origin (as URDF and MJCF give them) or prismatic."""
        return _levels.takes(self)

    def forward_by_depth(self, q: jax.Array, base: jax.Array) -> _levels.LevelPass:
        """The forward pass as arrays, the bodies of one depth of the tree at a time
        (:mod:`diffkin.models._levels`): for a consumer that reads every joint's screw and many bodies as
        arrays (the IK's Jacobian of a whole robot), a few kernels where the unrolled pass's entries
        gathered into arrays are one each. Only where :attr:`by_depth`.

        Args:
            q: ``(dof,) + batch`` joint values.
            base: ``(3, 4) + batch`` (or ``(3, 4)``): ``T_world_root`` ``[R p]``.
        """
        if not self.by_depth:
            raise ValueError(f"robot {self.name!r}: the pass by depth takes trees of one-axis joints only")
        return _levels.forward(self, q, base)

    def tree_pass(self, q: Sequence[rg.Entry], base: rg.Rigid = rg.IDENTITY) -> RobotPass:
        """The pass of the tree at the values ``q`` of ``q``'s entries and then of the dependent joints
        (:attr:`dependent_names`, solved by :meth:`forward`)."""
        if self.scanned:
            if self.loop_bodies:
                raise ValueError(
                    f"robot {self.name!r}: closed loops on a path of more than {_scanned.LONG} joints are not supported"
                )
            if "B" in self.joint_types:
                raise ValueError(
                    f"robot {self.name!r}: a path of more than {_scanned.LONG} joints with ball joints is not "
                    "supported (the scanned forward pass takes one-axis joints)"
                )
            return _scanned.forward(self, q, base)
        P, S, m, o = (host(x) for x in (self.joint_poses, self.screws, self.multipliers, self.offsets))
        m, o = rg.per_joint(m), rg.per_joint(o)
        axes = [(rg.vector(S[j, :3]), rg.vector(S[j, 3:])) for j in range(len(self.parents))]
        thetas = [rg.add(rg.mul(m[j], q[self.sources[j]]), o[j]) for j in range(len(self.parents))]
        balls = {j + k: j for j in _ball.starts(self.joint_types) for k in range(3)}  # tree joint -> its ball's first
        single = [j for j in range(len(self.parents)) if j not in balls]
        exps = dict(zip(single, rg.screw_exps([axes[j] for j in single], [thetas[j] for j in single]), strict=True))
        bodies, screws = [base], []
        depth, inner = [0], {parent for parent in self.parents}  # joints from the root; bodies with children
        for j, parent in enumerate(self.parents):
            T = rg.compose(bodies[parent], rg.from_matrix(P[j]))
            if j in balls:  # a ball joint moves its third body by one rotation; the two between stay at T
                if balls[j] == j:
                    T_child, ball_screws = _ball.motion(axes[j : j + 3], thetas[j : j + 3], T)
                screws.append(ball_screws[j - balls[j]])
                T = T_child if j == balls[j] + 2 else T
            else:
                v, w = axes[j]
                w_world = rg.rotate(T.R, w)
                screws.append((rg.vadd(rg.rotate(T.R, v), rg.cross(T.p, w_world)), w_world))
                T = rg.compose(T, exps[j])
            depth.append(depth[parent] + 1)
            if depth[-1] % _xla.SEGMENT == 0 and j + 1 in inner:  # a long serial path: see _xla.segment_end
                T = rg.checkpoint(T)
            bodies.append(T)
        return RobotPass(self, bodies, screws, m)

    def chain(self, end: str, base: str | None = None) -> PoEChain:
        """The exact :class:`PoEChain` of the path from frame ``base`` (default the root) to frame ``end``.

        The chain's world frame is ``base``; its joints are the moving joints on the path (in
        order), each driven by its actuated source joint (the chain's ``joint_names``, limits
        and ``q`` are those of the sources). A mimic joint on the path is folded into its source
        (screw times the multiplier, offset folded into the poses), which is exact when the
        multiplier is ``+-1`` and the source drives no other joint on the path. Differentiable
        with respect to the robot's arrays.

        Raises:
            ValueError: unknown frames, ``base`` not an ancestor of ``end``, no moving joint on
                the path, or a mimic coupling that a serial chain cannot express.
        """
        f_end = self.frame_index(end)
        f_base = self.frame_index(base) if base is not None else 0
        b_end, b_base = self.frame_bodies[f_end], self.frame_bodies[f_base]
        path = self.ancestors(b_end)
        below = self.ancestors(b_base)
        if path[: len(below)] != below:
            raise ValueError(f"chain: frame {end!r} is not below frame {self.frame_names[f_base]!r}")
        path = path[len(below) :]
        if not path:
            raise ValueError(f"chain: no moving joint between {self.frame_names[f_base]!r} and {end!r}")
        balls = [self.tree_joints[j] for j in path if self.joint_types[j] == "B"]
        if balls:
            raise ValueError(
                f"chain: the path to {end!r} has a ball joint ({balls[0]!r}), which a chain of one-axis joints "
                "cannot hold; use the robot itself (dk.fk, dk.jacobian and dk.ik.solve take it)"
            )
        solved = [self.tree_joints[j] for j in path if self.sources[j] >= self.dof]
        if solved:
            raise ValueError(f"chain: joint {solved[0]!r} on the path to {end!r} closes a loop; use the robot itself")
        sources = [self.sources[j] for j in path]
        m_host = np.asarray(self.multipliers, np.float64) if is_concrete(self.multipliers) else None
        for j in path:
            if sources.count(self.sources[j]) > 1:
                driven = [self.tree_joints[k] for k in path if self.sources[k] == self.sources[j]]
                raise ValueError(
                    f"chain: joint {self.joint_names[self.sources[j]]!r} drives several joints on the "
                    f"path to {end!r} ({driven}); a serial chain has one joint per variable"
                )
            if m_host is not None and abs(abs(m_host[j]) - 1.0) > 1e-12:
                raise ValueError(
                    f"chain: mimic joint {self.tree_joints[j]!r} has multiplier {m_host[j]}; a serial chain needs +-1"
                )
        dtype = jnp.result_type(self.joint_poses)
        T = rg.inverse(rg.from_matrix(self.frame_poses[f_base]))
        screws, link_homes = [], []
        for j in path:
            T = rg.compose(T, rg.from_matrix(self.joint_poses[j]))
            v, w = rg.vector(self.screws[j, :3]), rg.vector(self.screws[j, 3:])
            T = rg.compose(T, rg.screw_exp(v, w, rg.constant(self.offsets[j])))
            w_now = rg.rotate(T.R, w)
            m = rg.constant(self.multipliers[j])
            v_now = rg.vadd(rg.rotate(T.R, v), rg.cross(T.p, w_now))
            screws.append(rg.stack([*rg.scale(m, v_now), *rg.scale(m, w_now)], (), dtype))
            link_homes.append(rg.to_matrix(T, (), dtype))
        home = rg.to_matrix(rg.compose(T, rg.from_matrix(self.frame_poses[f_end])), (), dtype)
        return PoEChain(
            screws=jnp.stack(screws),
            home=home,
            link_homes=jnp.stack(link_homes),
            lower=self.lower[jnp.asarray(sources)],
            upper=self.upper[jnp.asarray(sources)],
            velocity=self.velocity[jnp.asarray(sources)],
            joint_types="".join(self.joint_types[j] for j in path),
            joint_names=tuple(self.joint_names[i] for i in sources),
            name=self.name,
        )
