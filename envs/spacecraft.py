"""MuJoCo spacecraft: a free-floating rigid bus with three or four reaction wheels.

The MJCF template ``envs/assets/spacecraft.xml`` holds the bus, the physics options (gravity 0,
contact disabled, RK4, free-joint damping 0) and the visual geoms. :class:`Spacecraft` reads it with
:class:`mujoco.MjSpec`, sets the bus inertia and adds the wheels (hinge joints + motor actuators),
then wraps the compiled model with named accessors so that no other code indexes ``qpos``/``qvel``.

Model
-----
All wheels sit at the bus centre of mass, so the spacecraft's centre of mass never moves and the
rotational dynamics decouple from translation. ``inertia_kg_m2`` is the **total** inertia of the
spacecraft with the wheels locked (bus + wheels); the bus body receives that minus the wheels'
inertia. With ``A`` the (3, n) matrix of wheel spin axes (body frame), ``I_s`` the wheel spin
inertia and ``Omega`` the wheel speeds relative to the bus (the hinge velocities), the total angular
momentum about the centre of mass is

    H_body = J ω + h_w,    h_w = I_s A Ω     (``wheel_momentum_body``)

and the equations of motion MuJoCo integrates are

    J ω̇ + I_s A Ω̇ = -ω × H_body,    I_s (a_iᵀ ω̇ + Ω̇_i) = τ_i,

with τ_i the motor torque on wheel i (the bus feels -Σ τ_i a_i). Motor torques are internal:
H_world = R(q) H_body is conserved unless an external torque is set.

Wheel limits: the commanded torque is clipped to ``±wheel_max_torque_Nm``; a wheel at its speed
limit receives no torque that would spin it faster (checked every physics substep, so a wheel
never exceeds the limit by more than one substep's worth of coupling from the bus motion).
Optional friction: Coulomb (``wheel_friction_Nm``, MuJoCo ``frictionloss``) and viscous
(``wheel_viscous_Nm_s``, joint ``damping``), both internal torques between wheel and bus.

The module is over 600 lines because it is one physics object (:class:`Spacecraft`): the MJCF build, the
state accessors, the wheel limits and the recording integrator share the model's private layout.
"""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np

from startracker.validation import as_float_array

__all__ = ["Spacecraft", "pyramid_wheel_axes", "ASSET_PATH"]

ASSET_PATH = Path(__file__).resolve().parent / "assets" / "spacecraft.xml"

#: Default pyramid elevation of the four wheel axes above the body x-y plane: tan(e) = 1/2 gives the
#: same momentum and torque envelope (2 cos e = 4 sin e) along the three body axes.
PYRAMID_ELEVATION_DEG = math.degrees(math.atan(0.5))


def pyramid_wheel_axes(elevation_deg: float = PYRAMID_ELEVATION_DEG) -> np.ndarray:
    """Spin axes of four wheels in a pyramid about body +z.

    Parameters
    ----------
    elevation_deg : float
        Angle of each axis above the body x-y plane, deg, in (0, 90). Azimuths are 0, 90, 180, 270 deg.

    Returns
    -------
    ndarray, shape (4, 3)
        Unit spin axes in the body frame, one row per wheel.
    """
    e = float(elevation_deg)
    if not (0.0 < e < 90.0):
        raise ValueError(f"elevation_deg must lie in (0, 90), got {elevation_deg}")
    ce, se = math.cos(math.radians(e)), math.sin(math.radians(e))
    az = np.radians([0.0, 90.0, 180.0, 270.0])
    return np.stack([ce * np.cos(az), ce * np.sin(az), np.full(4, se)], axis=1)


def _positive_scalar_or_per_wheel(value, name: str, n: int, allow_zero: bool = False) -> np.ndarray:
    arr = as_float_array(value, name)
    if arr.ndim == 0:
        arr = np.full(n, float(arr))
    if arr.shape != (n,):
        raise ValueError(f"{name} must be a scalar or have shape ({n},), got {arr.shape}")
    if np.any(arr < 0.0) or (not allow_zero and np.any(arr == 0.0)):
        bound = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"{name} must be {bound}, got {value}")
    return arr


def _inertia_matrix(inertia_kg_m2) -> np.ndarray:
    j = as_float_array(inertia_kg_m2, "inertia_kg_m2")
    if j.shape == (3,):
        j = np.diag(j)
    if j.shape != (3, 3):
        raise ValueError(f"inertia_kg_m2 must have shape (3,) (principal moments) or (3, 3), got {j.shape}")
    if not np.allclose(j, j.T, rtol=0.0, atol=1e-12 * max(1.0, np.abs(j).max())):
        raise ValueError("inertia_kg_m2 must be symmetric")
    return 0.5 * (j + j.T)


def _check_physical_inertia(j: np.ndarray, name: str) -> None:
    """Positive definite and principal moments obey the triangle inequality (A + B >= C)."""
    ev = np.linalg.eigvalsh(j)
    if ev[0] <= 0.0:
        raise ValueError(f"{name} must be positive definite, eigenvalues {ev}")
    if ev[0] + ev[1] < ev[2] * (1.0 - 1e-9):
        raise ValueError(f"{name} principal moments {ev} violate the triangle inequality A + B >= C")


class Spacecraft:
    """Free-floating spacecraft with reaction wheels, simulated by MuJoCo (RK4).

    Parameters
    ----------
    inertia_kg_m2 : array_like, shape (3,) or (3, 3), optional
        Total inertia of the spacecraft about its centre of mass in the body frame, wheels included,
        kg m². A (3,) value is the diagonal. Default ``(5, 6, 4)``: a ~50 kg microsatellite.
    n_wheels : {3, 4}
        Three wheels on the body axes, or four in a pyramid (:func:`pyramid_wheel_axes`). Default 4.
    wheel_axes_body : array_like, shape (n_wheels, 3), optional
        Custom spin axes (normalised here); they must span 3-D. Overrides the default layout.
    wheel_inertia_kg_m2 : float
        Spin-axis inertia of each wheel, kg m². Default 0.01 (transverse inertia 0.6 of it).
    wheel_max_torque_Nm : float or array_like (n_wheels,)
        Motor torque limit, N m. Default 0.5 (a 20 deg/s rate is reached in ~5 s about any axis).
    wheel_max_speed_rad_s : float or array_like (n_wheels,)
        Wheel speed limit relative to the bus, rad/s. Default 600 (~5730 rpm, 6 N m s per wheel).
    wheel_friction_Nm : float
        Coulomb friction torque of each bearing, N m (MuJoCo ``frictionloss``). Default 0.
    wheel_viscous_Nm_s : float
        Viscous friction coefficient of each bearing, N m s/rad. Default 0.
    timestep_s : float
        MuJoCo (RK4) substep, s. Default 0.01: momentum is conserved to ~1e-12 relative.
    mass_kg : float
        Total mass (only used to give the free body a mass; no force acts on it). Default 50.

    Notes
    -----
    The object pickles (it rebuilds the MuJoCo model from its constructor arguments and restores
    the :meth:`get_state` snapshot). ``model`` and ``data`` are exposed for rendering only.
    """

    def __init__(
        self,
        *,
        inertia_kg_m2=(5.0, 6.0, 4.0),
        n_wheels: int = 4,
        wheel_axes_body=None,
        wheel_inertia_kg_m2: float = 0.01,
        wheel_max_torque_Nm=0.5,
        wheel_max_speed_rad_s=600.0,
        wheel_friction_Nm: float = 0.0,
        wheel_viscous_Nm_s: float = 0.0,
        timestep_s: float = 0.01,
        mass_kg: float = 50.0,
    ):
        self._kwargs = dict(
            inertia_kg_m2=inertia_kg_m2,
            n_wheels=n_wheels,
            wheel_axes_body=wheel_axes_body,
            wheel_inertia_kg_m2=wheel_inertia_kg_m2,
            wheel_max_torque_Nm=wheel_max_torque_Nm,
            wheel_max_speed_rad_s=wheel_max_speed_rad_s,
            wheel_friction_Nm=wheel_friction_Nm,
            wheel_viscous_Nm_s=wheel_viscous_Nm_s,
            timestep_s=timestep_s,
            mass_kg=mass_kg,
        )
        if isinstance(n_wheels, bool) or not isinstance(n_wheels, (int, np.integer)):
            raise TypeError(f"n_wheels must be an int (3 or 4), got {type(n_wheels).__name__}")
        if wheel_axes_body is None:
            if n_wheels == 3:
                axes = np.eye(3)
            elif n_wheels == 4:
                axes = pyramid_wheel_axes()
            else:
                raise ValueError(f"n_wheels must be 3 or 4, got {n_wheels}")
        else:
            axes = as_float_array(wheel_axes_body, "wheel_axes_body", last_dim=3, ndim=2)
            if axes.shape[0] != n_wheels:
                raise ValueError(f"wheel_axes_body must have shape ({n_wheels}, 3), got {axes.shape}")
            if n_wheels < 3:
                raise ValueError(f"n_wheels must be >= 3 to control three axes, got {n_wheels}")
            norms = np.linalg.norm(axes, axis=1, keepdims=True)
            if np.any(norms < 1e-9):
                raise ValueError("wheel_axes_body contains a zero vector")
            axes = axes / norms
            if np.linalg.matrix_rank(axes, tol=1e-6) < 3:
                raise ValueError("wheel_axes_body must span three dimensions")
        n = int(n_wheels)
        self._n = n
        self._axes = axes.copy()
        self._axes.setflags(write=False)

        j_total = _inertia_matrix(inertia_kg_m2)
        _check_physical_inertia(j_total, "inertia_kg_m2")
        i_s = float(as_float_array(wheel_inertia_kg_m2, "wheel_inertia_kg_m2"))
        if not i_s > 0.0:
            raise ValueError(f"wheel_inertia_kg_m2 must be > 0, got {wheel_inertia_kg_m2}")
        i_t = 0.6 * i_s
        self._tau_max = _positive_scalar_or_per_wheel(wheel_max_torque_Nm, "wheel_max_torque_Nm", n)
        self._speed_max = _positive_scalar_or_per_wheel(wheel_max_speed_rad_s, "wheel_max_speed_rad_s", n)
        fric = float(as_float_array(wheel_friction_Nm, "wheel_friction_Nm"))
        visc = float(as_float_array(wheel_viscous_Nm_s, "wheel_viscous_Nm_s"))
        if fric < 0.0:
            raise ValueError(f"wheel_friction_Nm must be >= 0, got {wheel_friction_Nm}")
        if visc < 0.0:
            raise ValueError(f"wheel_viscous_Nm_s must be >= 0, got {wheel_viscous_Nm_s}")
        dt = float(as_float_array(timestep_s, "timestep_s"))
        if not (0.0 < dt <= 0.1):
            raise ValueError(f"timestep_s must lie in (0, 0.1], got {timestep_s}")
        mass = float(as_float_array(mass_kg, "mass_kg"))
        if not mass > 0.0:
            raise ValueError(f"mass_kg must be > 0, got {mass_kg}")
        wheel_mass = min(0.5, 0.02 * mass)

        # Inertia of each wheel about the common centre of mass (its own, since it sits there).
        wheel_inertias = [i_t * np.eye(3) + (i_s - i_t) * np.outer(a, a) for a in axes]
        j_bus = j_total - sum(wheel_inertias)
        try:
            _check_physical_inertia(j_bus, "bus inertia")
        except ValueError as exc:
            raise ValueError(
                f"inertia_kg_m2 is too small to contain {n} wheels of wheel_inertia_kg_m2={i_s}: {exc}"
            ) from None

        spec = mujoco.MjSpec.from_file(str(ASSET_PATH))
        spec.option.timestep = dt
        bus = spec.body("bus")
        bus.mass = mass - n * wheel_mass
        bus.ipos = [0.0, 0.0, 0.0]
        bus.inertia = [0.0, 0.0, 0.0]  # the template's diaginertia is replaced by fullinertia
        bus.fullinertia = _fullinertia(j_bus)
        bus.explicitinertial = True
        radius = 0.12
        for i, a in enumerate(axes):
            wb = bus.add_body(name=f"wheel{i}", pos=[0.0, 0.0, 0.0])
            wb.mass = wheel_mass
            # MjSpec quirk (mujoco 3.x/4.0): without an explicit ipos the compiler keeps the principal
            # moments of fullinertia but drops their orientation (iquat stays identity).
            wb.ipos = [0.0, 0.0, 0.0]
            wb.fullinertia = _fullinertia(wheel_inertias[i])
            wb.explicitinertial = True
            wb.add_joint(
                name=f"wheel{i}",
                type=mujoco.mjtJoint.mjJNT_HINGE,
                axis=list(a),
                damping=visc,
                frictionloss=fric,
                armature=0.0,
            )
            # visual only (density 0, no contact): a disc offset along its axis so the four are visible
            wb.add_geom(
                name=f"wheel{i}",
                type=mujoco.mjtGeom.mjGEOM_CYLINDER,
                size=[radius, 0.02, 0.0],
                fromto=list(np.concatenate([0.15 * a, 0.19 * a])),
                rgba=[0.6, 0.6, 0.6, 1.0],
            )
            act = spec.add_actuator(name=f"wheel{i}", target=f"wheel{i}", trntype=mujoco.mjtTrn.mjTRN_JOINT)
            act.set_to_motor()
            act.ctrllimited = True
            act.ctrlrange = [-self._tau_max[i], self._tau_max[i]]
        self.model = spec.compile()
        self.data = mujoco.MjData(self.model)
        m = self.model

        root = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, "root")
        qa, da = int(m.jnt_qposadr[root]), int(m.jnt_dofadr[root])
        self._sl_pos = slice(qa, qa + 3)
        self._sl_quat = slice(qa + 3, qa + 7)
        self._sl_vlin = slice(da, da + 3)
        self._sl_omega = slice(da + 3, da + 6)
        wq = [int(m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, f"wheel{i}")]) for i in range(n)]
        wd = [int(m.jnt_dofadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, f"wheel{i}")]) for i in range(n)]
        if wq != list(range(wq[0], wq[0] + n)) or wd != list(range(wd[0], wd[0] + n)):
            raise RuntimeError("wheel joints are not contiguous in qpos/qvel")  # cannot happen with this spec
        self._sl_wq = slice(wq[0], wq[0] + n)
        self._sl_wv = slice(wd[0], wd[0] + n)
        self._bus_id = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "bus")

        self._dt = dt
        self._i_s = i_s
        self._j_total = j_total
        self._j_total.setflags(write=False)
        self._lambda_min = float(np.linalg.eigvalsh(j_total - i_s * axes.T @ axes)[0])
        self._lambda_max = float(np.linalg.eigvalsh(j_total)[-1])
        self._speed_max_list = self._speed_max.tolist()
        self._torque_cmd = np.zeros(n)
        self._axes_pinv = np.linalg.pinv(axes.T)  # (n, 3)
        mujoco.mj_forward(m, self.data)

    # ------------------------------------------------------------------ configuration
    @property
    def n_wheels(self) -> int:
        """Number of reaction wheels."""
        return self._n

    @property
    def inertia_kg_m2(self) -> np.ndarray:
        """Total inertia (bus + locked wheels) in the body frame, shape (3, 3), kg m²."""
        return self._j_total.copy()

    @property
    def wheel_axes_body(self) -> np.ndarray:
        """Wheel spin axes in the body frame, shape (n_wheels, 3), one unit row per wheel."""
        return self._axes.copy()

    @property
    def wheel_inertia_kg_m2(self) -> float:
        """Spin-axis inertia of each wheel, kg m²."""
        return self._i_s

    @property
    def wheel_max_torque_Nm(self) -> np.ndarray:
        """Motor torque limits, shape (n_wheels,), N m."""
        return self._tau_max.copy()

    @property
    def wheel_max_speed_rad_s(self) -> np.ndarray:
        """Wheel speed limits relative to the bus, shape (n_wheels,), rad/s."""
        return self._speed_max.copy()

    @property
    def wheel_max_momentum_Nms(self) -> np.ndarray:
        """Momentum capacity of each wheel, ``I_s * max speed``, shape (n_wheels,), N m s."""
        return self._i_s * self._speed_max

    @property
    def timestep_s(self) -> float:
        """MuJoCo substep, s."""
        return self._dt

    # ------------------------------------------------------------------ state accessors
    @property
    def time_s(self) -> float:
        """Simulation time, s."""
        return float(self.data.time)

    @property
    def q_body_to_icrs(self) -> np.ndarray:
        """Attitude quaternion (w, x, y, z), body -> world (ICRS), shape (4,)."""
        return self.data.qpos[self._sl_quat].copy()

    @property
    def omega_body(self) -> np.ndarray:
        """Bus angular velocity in the body frame, shape (3,), rad/s (MuJoCo's free-joint ``qvel[3:6]``)."""
        return self.data.qvel[self._sl_omega].copy()

    @property
    def wheel_angles_rad(self) -> np.ndarray:
        """Wheel rotation angles relative to the bus, shape (n_wheels,), rad."""
        return self.data.qpos[self._sl_wq].copy()

    @property
    def wheel_speeds_rad_s(self) -> np.ndarray:
        """Wheel speeds relative to the bus, shape (n_wheels,), rad/s."""
        return self.data.qvel[self._sl_wv].copy()

    @property
    def wheel_momentum_body(self) -> np.ndarray:
        """Relative wheel momentum ``h_w = I_s A Ω`` in the body frame, shape (3,), N m s."""
        return self._i_s * (self.data.qvel[self._sl_wv] @ self._axes)

    @property
    def wheel_momentum_fraction(self) -> np.ndarray:
        """Wheel speeds as a fraction of their limits, shape (n_wheels,), in [-1, 1] (up to one substep over)."""
        return self.data.qvel[self._sl_wv] / self._speed_max

    @property
    def total_angular_momentum_body(self) -> np.ndarray:
        """Total angular momentum about the centre of mass in the body frame, ``J ω + h_w``, (3,), N m s."""
        return self._j_total @ self.data.qvel[self._sl_omega] + self.wheel_momentum_body

    @property
    def total_angular_momentum_world(self) -> np.ndarray:
        """Total angular momentum about the centre of mass in the inertial (ICRS) frame, shape (3,), N m s."""
        # not data.xmat: after mj_step it still holds the kinematics of the previous substep
        w, x, y, z = self.data.qpos[self._sl_quat]
        r = np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
            ]
        )
        return r @ self.total_angular_momentum_body

    @property
    def applied_wheel_torque_Nm(self) -> np.ndarray:
        """Motor torques applied in the last substep (after torque and speed limiting), (n_wheels,), N m."""
        return self.data.ctrl.copy()

    @property
    def commanded_wheel_torque_Nm(self) -> np.ndarray:
        """Motor torques last commanded with :meth:`apply_wheel_torque` (torque-clipped), (n_wheels,), N m."""
        return self._torque_cmd.copy()

    # ------------------------------------------------------------------ commands
    def set_state(self, q_body_to_icrs, omega_body, wheel_speeds_rad_s=None, time_s: float | None = None) -> None:
        """Set the physical state (position stays at the origin, wheel angles are kept).

        Parameters
        ----------
        q_body_to_icrs : array_like, shape (4,)
            Attitude (w, x, y, z); normalised here.
        omega_body : array_like, shape (3,)
            Bus angular velocity, body frame, rad/s.
        wheel_speeds_rad_s : array_like, shape (n_wheels,), optional
            Wheel speeds relative to the bus, rad/s, each within its limit. Default: unchanged.
        time_s : float, optional
            Simulation time, s. Default: unchanged.
        """
        q = as_float_array(q_body_to_icrs, "q_body_to_icrs", last_dim=4, ndim=1)
        nq = np.linalg.norm(q)
        if nq < 1e-12:
            raise ValueError("q_body_to_icrs must be a non-zero quaternion")
        w = as_float_array(omega_body, "omega_body", last_dim=3, ndim=1)
        ws = None
        if wheel_speeds_rad_s is not None:
            ws = as_float_array(wheel_speeds_rad_s, "wheel_speeds_rad_s", ndim=1)
            if ws.shape != (self._n,):
                raise ValueError(f"wheel_speeds_rad_s must have shape ({self._n},), got {ws.shape}")
            if np.any(np.abs(ws) > self._speed_max * (1 + 1e-9)):
                raise ValueError(f"wheel_speeds_rad_s must lie within ±{self._speed_max} rad/s, got {ws}")
        t = None if time_s is None else float(as_float_array(time_s, "time_s"))
        # everything validated: now write
        if ws is not None:
            self.data.qvel[self._sl_wv] = ws
        if t is not None:
            self.data.time = t
        self.data.qpos[self._sl_pos] = 0.0
        self.data.qvel[self._sl_vlin] = 0.0
        self.data.qpos[self._sl_quat] = q / nq
        self.data.qvel[self._sl_omega] = w
        mujoco.mj_forward(self.model, self.data)

    def reset(self, q_body_to_icrs, omega_body, wheel_speeds_rad_s=None, time_s: float = 0.0) -> None:
        """Start afresh: MuJoCo's data back to the model's defaults (wheel angles, commands, external torque,
        solver warm start), then :meth:`set_state`.

        What :meth:`set_state` keeps (wheel angles, the held torque command, the disturbance torque, MuJoCo's
        warm start and activations) changes the arithmetic of the next substeps in the last bits, so a second
        episode from the same state would not repeat the first bit for bit; after this call it does.

        Parameters
        ----------
        q_body_to_icrs : array_like, shape (4,)
            Attitude (w, x, y, z); normalised here.
        omega_body : array_like, shape (3,)
            Bus angular velocity, body frame, rad/s.
        wheel_speeds_rad_s : array_like, shape (n_wheels,), optional
            Wheel speeds relative to the bus, rad/s. Default: at rest.
        time_s : float
            Simulation time, s. Default 0.
        """
        ws = np.zeros(self._n) if wheel_speeds_rad_s is None else wheel_speeds_rad_s
        saved = self.get_state()
        mujoco.mj_resetData(self.model, self.data)
        self._torque_cmd[:] = 0.0
        try:
            self.set_state(q_body_to_icrs, omega_body, ws, time_s=time_s)
        except (TypeError, ValueError):
            self.restore_state(saved)  # bad input leaves the spacecraft as it was
            raise

    def apply_wheel_torque(self, torque_Nm, *, validate: bool = True) -> np.ndarray:
        """Command motor torques, held until the next call.

        Parameters
        ----------
        torque_Nm : array_like, shape (n_wheels,)
            Torque of each motor on its wheel about the wheel axis, N m (the bus feels the opposite).
            Clipped to ``±wheel_max_torque_Nm``.
        validate : bool
            False skips the checks, for a caller passing a finite float64 array of shape (n_wheels,) (the env's
            checked action).

        Returns
        -------
        ndarray, shape (n_wheels,)
            The clipped command.
        """
        if validate:
            t = as_float_array(torque_Nm, "torque_Nm", ndim=1)
            if t.shape != (self._n,):
                raise ValueError(f"torque_Nm must have shape ({self._n},), got {t.shape}")
        else:
            t = torque_Nm
        # np.clip's arithmetic (max then min) without its dispatch
        np.minimum(np.maximum(t, -self._tau_max), self._tau_max, out=self._torque_cmd)
        self.data.ctrl[:] = self._torque_cmd
        return self._torque_cmd.copy()

    def body_torque_to_wheel_torque(self, torque_body_Nm) -> np.ndarray:
        """Minimum-norm motor torques producing a reaction torque on the bus.

        Solves ``-A τ = torque_body`` with the pseudo-inverse; if a motor would exceed its limit the
        whole vector is scaled down so that the torque direction is kept.

        Parameters
        ----------
        torque_body_Nm : array_like, shape (3,)
            Desired torque on the bus, body frame, N m.

        Returns
        -------
        ndarray, shape (n_wheels,)
            Motor torques on the wheels, N m, within limits.
        """
        tb = as_float_array(torque_body_Nm, "torque_body_Nm", last_dim=3, ndim=1)
        tau = -(self._axes_pinv @ tb)
        over = float(np.max(np.abs(tau) / self._tau_max))
        return tau / over if over > 1.0 else tau

    def set_external_torque_world(self, torque_world_Nm) -> None:
        """Apply an external (disturbance) torque on the bus, inertial (ICRS) frame, N m, held until changed.

        Parameters
        ----------
        torque_world_Nm : array_like, shape (3,)
        """
        t = as_float_array(torque_world_Nm, "torque_world_Nm", last_dim=3, ndim=1)
        self.data.xfrc_applied[self._bus_id, 3:6] = t

    def step(self, duration_s: float) -> None:
        """Integrate ``duration_s`` seconds (a whole number of substeps) with the held commands.

        Parameters
        ----------
        duration_s : float
            Positive multiple of ``timestep_s`` (to 1e-6 relative), s.
        """
        d = float(duration_s)
        if not (math.isfinite(d) and d > 0.0):
            raise ValueError(f"duration_s must be a positive finite number, got {duration_s}")
        n_sub = round(d / self._dt)
        if n_sub < 1 or abs(n_sub * self._dt - d) > 1e-6 * d:
            raise ValueError(f"duration_s={d} must be a whole multiple of timestep_s={self._dt}")
        m, data = self.model, self.data
        # Fast path: no wheel can reach its speed limit within the step. Bound on the relative wheel
        # acceleration: motor torque / I_s plus the coupling a·ω̇ through the bus, with
        # |ω̇| <= (Σ|τ| + |τ_ext| + |ω| |H|) / λ_min(J - I_s A Aᵀ) and |H| <= λ_max(J) |ω| + I_s Σ|Ω|.
        # Plain floats (n <= 4): this check costs ~2 µs, a fraction of one RK4 substep.
        speeds = data.qvel[self._sl_wv].tolist()
        tau = self._torque_cmd.tolist()
        wx, wy, wz = data.qvel[self._sl_omega].tolist()
        wn = math.sqrt(wx * wx + wy * wy + wz * wz)
        h_bound = self._lambda_max * wn + self._i_s * sum(abs(v) for v in speeds)
        ex, ey, ez = data.xfrc_applied[self._bus_id, 3:6].tolist()
        t_ext = math.sqrt(ex * ex + ey * ey + ez * ez)
        coupling = (sum(abs(v) for v in tau) + t_ext + wn * h_bound) / self._lambda_min
        horizon = 1.5 * d
        if all(
            abs(sp) + horizon * (abs(tq) / self._i_s + coupling) < smax
            for sp, tq, smax in zip(speeds, tau, self._speed_max_list)
        ):
            data.ctrl[:] = self._torque_cmd
            mujoco.mj_step(m, data, nstep=n_sub)
            return
        tau = self._torque_cmd
        dt = self._dt
        for _ in range(n_sub):
            speeds = data.qvel[self._sl_wv]
            ctrl = tau.copy()
            accel = speeds * np.sign(tau) > -1e-12  # torque would speed the wheel up (or it is at rest)
            room = np.maximum(self._speed_max - np.abs(speeds), 0.0) * self._i_s / dt
            limited = accel & (np.abs(tau) > room)
            ctrl[limited] = np.sign(tau[limited]) * room[limited]
            data.ctrl[:] = ctrl
            mujoco.mj_step(m, data)

    def step_recording(self, substep_s: float, n_steps: int, *, include_start: bool = False
                       ) -> tuple[np.ndarray, np.ndarray]:
        """Integrate ``n_steps`` substeps of ``substep_s`` with the held commands, recording the truth history.

        Equal to ``n_steps`` calls of :meth:`step` (``substep_s`` each), reading :attr:`time_s` and
        :attr:`q_body_to_icrs` after each. The fast path of :meth:`step` is decided once for the whole span
        (its bound with the horizon of all ``n_steps``); when it holds, no wheel limit can engage and each
        substep is the same ``mj_step`` that :meth:`step` would run. Otherwise every substep goes through
        :meth:`step`.

        Parameters
        ----------
        substep_s : float
            Duration of one recorded substep, s: a positive multiple of :attr:`timestep_s`.
        n_steps : int
            Number of substeps (>= 1).
        include_start : bool
            Also record the state before the first substep, as row 0 (the history an observer of the span needs).

        Returns
        -------
        times_s : ndarray, shape (n_steps,), or (n_steps + 1,) with ``include_start``
            Time after each substep, s.
        q_body_to_icrs : ndarray, shape (n_steps, 4), or (n_steps + 1, 4) with ``include_start``
            True attitude after each substep (w, x, y, z).
        """
        if isinstance(n_steps, bool) or int(n_steps) != n_steps or n_steps < 1:
            raise ValueError(f"n_steps must be an integer >= 1, got {n_steps!r}")
        n_steps = int(n_steps)
        duration_s = float(substep_s)
        if not (math.isfinite(duration_s) and duration_s > 0.0):
            raise ValueError(f"substep_s must be a positive finite number, got {substep_s!r}")
        data, m = self.data, self.model
        # a view of MjData's own buffer (mj_step writes in place): one slice per span, not one per substep
        q_now = data.qpos[self._sl_quat]
        first = 1 if include_start else 0
        times_out = np.empty(n_steps + first)
        quats_out = np.empty((n_steps + first, 4))
        if first:
            times_out[0] = data.time
            quats_out[0] = q_now
        speeds = data.qvel[self._sl_wv].tolist()
        tau = self._torque_cmd.tolist()
        wx, wy, wz = data.qvel[self._sl_omega].tolist()
        wn = math.sqrt(wx * wx + wy * wy + wz * wz)
        h_bound = self._lambda_max * wn + self._i_s * sum(abs(v) for v in speeds)
        ex, ey, ez = data.xfrc_applied[self._bus_id, 3:6].tolist()
        t_ext = math.sqrt(ex * ex + ey * ey + ez * ez)
        coupling = (sum(abs(v) for v in tau) + t_ext + wn * h_bound) / self._lambda_min
        horizon = 1.5 * float(duration_s) * n_steps
        fast = abs(float(duration_s) - self._dt) <= 1e-6 * self._dt and all(
            abs(sp) + horizon * (abs(tq) / self._i_s + coupling) < smax
            for sp, tq, smax in zip(speeds, tau, self._speed_max_list)
        )
        if fast:
            data.ctrl[:] = self._torque_cmd
            for k in range(first, n_steps + first):
                mujoco.mj_step(m, data)
                times_out[k] = data.time
                quats_out[k] = q_now
            return times_out, quats_out
        for k in range(first, n_steps + first):
            self.step(duration_s)
            times_out[k] = data.time
            quats_out[k] = q_now
        return times_out, quats_out

    # ------------------------------------------------------------------ snapshots and pickling
    @property
    def state_size(self) -> int:
        """Length of the :meth:`get_state` vector: ``1 + nq + nv + n_wheels + 3``."""
        return 1 + self.model.nq + self.model.nv + self._n + 3

    def get_state(self) -> np.ndarray:
        """Snapshot ``[time, qpos, qvel, commanded torques, external torque (world)]``, shape (state_size,)."""
        return np.concatenate(
            [[self.data.time], self.data.qpos, self.data.qvel, self._torque_cmd, self.data.xfrc_applied[self._bus_id, 3:6]]
        )

    def restore_state(self, state) -> None:
        """Restore a :meth:`get_state` snapshot of a spacecraft built with the same arguments.

        Parameters
        ----------
        state : array_like, shape (state_size,)
        """
        s = as_float_array(state, "state", ndim=1)
        if s.shape != (self.state_size,):
            raise ValueError(f"state must have shape ({self.state_size},), got {s.shape}")
        nq, nv, n = self.model.nq, self.model.nv, self._n
        self.data.time = s[0]
        self.data.qpos[:] = s[1 : 1 + nq]
        self.data.qvel[:] = s[1 + nq : 1 + nq + nv]
        self._torque_cmd[:] = s[1 + nq + nv : 1 + nq + nv + n]
        self.data.ctrl[:] = self._torque_cmd
        self.data.xfrc_applied[self._bus_id, 3:6] = s[1 + nq + nv + n :]
        mujoco.mj_forward(self.model, self.data)

    def __getstate__(self):
        return {"kwargs": self._kwargs, "state": self.get_state()}

    def __setstate__(self, d):
        self.__init__(**d["kwargs"])
        self.restore_state(d["state"])

    def __repr__(self) -> str:
        return (
            f"Spacecraft(n_wheels={self._n}, inertia_diag={np.diag(self._j_total).round(4).tolist()}, "
            f"wheel_max_torque_Nm={self._tau_max.tolist()}, wheel_max_speed_rad_s={self._speed_max.tolist()}, "
            f"timestep_s={self._dt})"
        )


def _fullinertia(j: np.ndarray) -> list[float]:
    """MuJoCo ``fullinertia`` order: ixx iyy izz ixy ixz iyz."""
    return [j[0, 0], j[1, 1], j[2, 2], j[0, 1], j[0, 2], j[1, 2]]
