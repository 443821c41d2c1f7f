"""The emulated UR5e: the project's MuJoCo arm (plants/arm.py) driven by simple stand-ins for the
robot controller's own loops (docs/ur_emulator.md, "What it emulates"). One `cycle()` is one controller
period (2 ms at 500 Hz), split into `substeps` MuJoCo steps.

Modes: "hold" (joint PD on the held joint positions: the robot at rest, a program stopped, a
protective stop), "servo" (servoL: Jacobian IK of the target pose, then a joint-space PD with
natural frequency sqrt(gain) rad/s, critically damped, through the mass matrix), "speed" (speedL:
the Cartesian twist through the Jacobian's pseudo-inverse, ramped at the commanded acceleration,
tracked by the same joint PD on the integrated reference), "force" (forceMode: the commanded
wrench as J^T w in the compliant axes of the task frame with damping there, a stiff Cartesian
spring on the pose held at entry in the others), "torque" (direct torque: the joint torques as
given, beyond gravity). Gravity is compensated by the model (gravcomp through the motors) in every
mode, as the real controller does.

Joint faults (`joint_fault`, injected through the test channel): "no_torque", a joint whose motor
applies nothing (neither the command nor gravity compensation) while the controller still reports
it running; "brake", a joint held by its brake, its motor off, reported IDLE. The mode's torque
stays the controller's target (`tau_target`); `tau_applied` is what MuJoCo's motors did, which
RTDE reports as `actual_current_as_torque` (docs/ur.md, "Applied, not commanded").
"""

from __future__ import annotations

import math

import numpy as np

from haptic_teleop.core.spatial import matrix_to_rotvec, orientation_error, rotvec_to_matrix
from haptic_teleop.plants.arm import MujocoArm, WallSpec
from haptic_teleop.plants.mujoco_plant import SimSettings

HOLD_OMEGA_RAD_PER_S = 40.0
CART_STIFFNESS_N_PER_M = 8000.0
CART_STIFFNESS_NM_PER_RAD = 400.0
FORCE_HOLD_RATE_PER_S = 20.0  # force mode's non-compliant axes: velocity per unit of pose error


class SimulatedUR:
    def __init__(
        self,
        model: str,
        start_q_rad: tuple[float, ...],
        period_s: float,
        substeps: int,
        wall: WallSpec | None,
        force_damping_n_s_per_m: float,
        force_damping_nm_s_per_rad: float,
    ) -> None:
        import mujoco

        self._mj = mujoco
        self.arm = MujocoArm(
            SimSettings(period_s=period_s, substeps=substeps),
            model,
            "tool",
            start_q_rad=list(start_q_rad),
            wall=wall,
        )
        self.period_s = period_s
        self.n = self.arm.n
        self.mode = "hold"
        q, _ = self.arm.read()
        self.q_hold = np.array(q)
        self.q_ref = np.array(q)
        self.qd_ref = np.zeros(self.n)
        self.servo_pose: np.ndarray | None = None
        self.servo_gain = 300.0
        self.twist_target = np.zeros(6)
        self.twist_now = np.zeros(6)
        self.accel = 0.5
        self._stopping = False
        self.force_frame = np.eye(3)
        self.force_sel = np.zeros(6)
        self.force_wrench = np.zeros(6)
        self.force_limits = np.zeros(6)
        self.force_hold_pos = np.zeros(3)
        self.force_hold_rot = np.eye(3)
        self.force_damp = (force_damping_n_s_per_m, force_damping_nm_s_per_rad)
        self.tau_direct = np.zeros(self.n)
        self.force_v = np.zeros(6)  # the force mode's admittance velocity (task frame)
        self.force_damping_value = 0.025  # ur_rtde's control script sets this at its start
        self.tau_applied = np.zeros(self.n)
        self.tau_target = np.zeros(self.n)  # the mode's torque beyond gravity, before any joint fault
        self.joint_faults: dict[int, str] = {}  # joint index -> "no_torque" or "brake"
        self._braked_q: dict[int, float] = {}
        self.ft_offset = np.zeros(6)
        self._mass = np.zeros((self.arm.model.nv, self.arm.model.nv))
        # Energy flows of the plant since start (J), per controller period: the motors' work beyond
        # gravity compensation tau^T dq, the joints' damping dissipation (its lower bound
        # d dq^2 / T, as EBA credits it), the work the tool did on the environment (-f_env . dx),
        # and the largest net motor work (work - dissipation) and tool work seen so far.
        self._damping = np.array(self.arm.joint_damping())
        self.motor_work_j = 0.0
        self.dissipated_j = 0.0
        self.env_work_j = 0.0
        self.max_net_motor_work_j = 0.0
        self.max_env_work_j = 0.0

    # ---------------------------------------------------------------- state
    def tcp_pose(self) -> np.ndarray:
        x, _ = self.arm.point()
        return np.concatenate([x, matrix_to_rotvec(self.arm.orientation())])

    def tcp_speed(self) -> np.ndarray:
        _, v = self.arm.point()
        return np.concatenate([v, self.arm.angular_velocity()])

    def tcp_force(self) -> np.ndarray:
        """The environment's wrench on the tool (force, torque about the TCP), base frame, minus the
        offset zeroFtSensor took."""
        f, t = self.arm.contact_wrench()
        return np.concatenate([f, t]) - self.ft_offset

    def zero_ft(self) -> None:
        f, t = self.arm.contact_wrench()
        self.ft_offset = np.concatenate([f, t])

    # ---------------------------------------------------------------- modes
    def hold(self) -> None:
        q, _ = self.arm.read()
        self.mode = "hold"
        self.q_hold = np.array(q)

    def servo_l(self, pose: np.ndarray, gain: float) -> None:
        if self.mode != "servo":
            q, _ = self.arm.read()
            self.q_ref = np.array(q)
        self.mode = "servo"
        self.servo_pose = np.array(pose, dtype=float)
        self.servo_gain = float(min(max(gain, 100.0), 2000.0))

    def speed_l(self, twist: np.ndarray, accel: float) -> None:
        if self.mode != "speed":
            q, _ = self.arm.read()
            self.q_ref = np.array(q)
            self.twist_now = np.zeros(6)
        self.mode = "speed"
        self._stopping = False
        self.twist_target = np.array(twist, dtype=float)
        self.accel = max(float(accel), 1e-3)

    def speed_stop(self, decel: float) -> None:
        if self.mode == "speed":
            self.twist_target = np.zeros(6)
            self.accel = max(float(decel), 1e-3)
            self._stopping = True

    def force_mode(self, frame: np.ndarray, selection: np.ndarray, wrench: np.ndarray, limits: np.ndarray) -> None:
        if self.mode != "force":
            x, _ = self.arm.point()
            self.force_hold_pos = np.array(x)
            self.force_hold_rot = self.arm.orientation()
            q, _ = self.arm.read()
            self.q_ref = np.array(q)
            self.force_v = np.zeros(6)
        self.mode = "force"
        self.force_frame = rotvec_to_matrix(np.asarray(frame[3:], dtype=float))
        self.force_sel = (np.asarray(selection) != 0).astype(float)
        self.force_wrench = np.array(wrench, dtype=float)
        self.force_limits = np.abs(np.array(limits, dtype=float))

    def force_mode_set_damping(self, damping: float) -> None:
        """URScript force_mode_set_damping: the share of the force-mode velocity lost per period with
        no force (0..1); the virtual mass follows from it and the damping (module docstring)."""
        self.force_damping_value = float(min(max(damping, 0.0), 1.0))

    def direct_torque(self, tau: np.ndarray) -> None:
        self.mode = "torque"
        self.tau_direct = np.array(tau, dtype=float)

    def set_joint_fault(self, joint: int, kind: str | None) -> None:
        """A joint stops applying its command ("no_torque": the motor applies nothing, the joint is
        free; "brake": the motor is off and the brake holds the joint where it is), or recovers (None)."""
        if kind is None:
            self.joint_faults.pop(joint, None)
            self._braked_q.pop(joint, None)
            return
        self.joint_faults[joint] = kind
        if kind == "brake":
            q, _ = self.arm.read()
            self._braked_q[joint] = float(q[joint])

    def joint_modes(self) -> list[int]:
        """RTDE joint_mode per joint: 253 RUNNING, 255 IDLE for a braked joint [RTDE guide]."""
        return [255 if self.joint_faults.get(k) == "brake" else 253 for k in range(self.n)]

    # ---------------------------------------------------------------- the loop
    def _mass_matrix(self) -> np.ndarray:
        self._mj.mj_fullM(self.arm.model, self.arm.data, self._mass)
        d = self.arm.constants().dof_adr
        return self._mass[np.ix_(d, d)]

    def _joint_pd(self, q_des: np.ndarray, qd_des: np.ndarray, omega: float) -> np.ndarray:
        q, qd = self.arm.read()
        acc = omega * omega * (q_des - q) + 2.0 * omega * (qd_des - qd)
        return self._mass_matrix() @ acc

    def _ik(self, pose: np.ndarray, q0: np.ndarray) -> np.ndarray:
        """Damped least-squares IK of the tool pose from q0 on a scratch copy of the model's data."""
        mj, m = self._mj, self.arm.model
        d = mj.MjData(m)
        adr = self.arm.constants()
        d.qpos[:] = self.arm.data.qpos
        q = np.array(q0, dtype=float)
        r_t = rotvec_to_matrix(pose[3:])
        site = adr.site_id
        jp, jr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
        for _ in range(8):
            d.qpos[adr.qpos_adr] = q
            mj.mj_kinematics(m, d)
            mj.mj_comPos(m, d)
            err = np.concatenate(
                [pose[:3] - d.site_xpos[site], orientation_error(r_t, d.site_xmat[site].reshape(3, 3))]
            )
            if np.linalg.norm(err) < 1e-9:
                break
            mj.mj_jacSite(m, d, jp, jr, site)
            j = np.vstack([jp[:, adr.dof_adr], jr[:, adr.dof_adr]])
            lam = 1e-4
            q = q + j.T @ np.linalg.solve(j @ j.T + lam * np.eye(6), err)
        return q

    def cycle(self) -> None:
        """One controller period: the active mode's torque, then the MuJoCo steps."""
        self.arm.read()
        if self.mode == "hold":
            tau = self._joint_pd(self.q_hold, np.zeros(self.n), HOLD_OMEGA_RAD_PER_S)
        elif self.mode == "servo":
            assert self.servo_pose is not None
            q_des = self._ik(self.servo_pose, self.q_ref)
            self.q_ref = q_des
            tau = self._joint_pd(q_des, np.zeros(self.n), math.sqrt(self.servo_gain))
        elif self.mode == "speed":
            step = self.accel * self.period_s
            dv = self.twist_target - self.twist_now
            n = float(np.linalg.norm(dv))
            self.twist_now = self.twist_target.copy() if n <= step else self.twist_now + dv * (step / n)
            j = self.arm.jacobian(rotational=True)
            qd_des = np.linalg.pinv(j) @ self.twist_now
            self.q_ref = self.q_ref + qd_des * self.period_s
            tau = self._joint_pd(self.q_ref, qd_des, HOLD_OMEGA_RAD_PER_S)
            if self._stopping and not self.twist_now.any():
                self.mode, self.q_hold = "hold", self.q_ref.copy()
        elif self.mode == "force":
            qd_des = self._force_joint_velocity()
            self.q_ref = self.q_ref + qd_des * self.period_s
            tau = self._joint_pd(self.q_ref, qd_des, HOLD_OMEGA_RAD_PER_S)
        else:  # torque
            tau = self.tau_direct.copy()
        self.tau_target = np.array(tau, dtype=float)
        if self.joint_faults:
            g = self.arm.gravity_torque()
            for k in self.joint_faults:
                tau[k] = -g[k]  # the motor applies nothing: not the command, not the gravity compensation
        q0 = np.array(self.arm.read()[0])
        x0, _ = self.arm.point()
        x0 = np.array(x0)
        self.tau_applied = self.arm.step(tau)
        if self._braked_q:
            adr = self.arm.constants()
            for k, qk in self._braked_q.items():  # the brake holds the joint: no motion in the period
                self.arm.data.qpos[adr.qpos_adr[k]] = qk
                self.arm.data.qvel[adr.dof_adr[k]] = 0.0
        q1, _ = self.arm.read()
        x1, _ = self.arm.point()
        dq = np.asarray(q1) - q0
        f_env, _ = self.arm.contact_wrench()
        self.motor_work_j += float(self.tau_applied @ dq)
        self.dissipated_j += float(self._damping @ (dq * dq)) / self.period_s
        self.env_work_j -= float(np.asarray(f_env) @ (np.asarray(x1) - x0))
        self.max_net_motor_work_j = max(self.max_net_motor_work_j, self.motor_work_j - self.dissipated_j)
        self.max_env_work_j = max(self.max_env_work_j, self.env_work_j)

    def _force_joint_velocity(self) -> np.ndarray:
        """Force mode as UR implements it, an admittance in velocity control: along each compliant
        axis of the task frame M v' + D v = w + f_ext (w the commanded wrench, f_ext the measured TCP
        wrench), discretised exactly for the period (v <- a v + (1 - a) (w + f_ext) / D with
        a = 1 - force_mode_set_damping, so M = -D h / ln a), clipped at the axis' speed limit; along
        the others a velocity back to the pose held at entry. The twist goes through the Jacobian's
        pseudo-inverse into the joint reference the joint PD tracks."""
        j = self.arm.jacobian(rotational=True)
        x, _ = self.arm.point()
        r = self.force_frame
        w_ext = self.tcp_force()  # the wrist sensor's reading (after zeroFtSensor)
        ext = np.concatenate([r.T @ w_ext[:3], r.T @ w_ext[3:]])
        damp = np.array([self.force_damp[0]] * 3 + [self.force_damp[1]] * 3)
        a = 1.0 - self.force_damping_value
        v = a * self.force_v + (1.0 - a) * (self.force_wrench + ext) / damp
        v = np.clip(v, -self.force_limits, self.force_limits)
        e_pos = r.T @ (self.force_hold_pos - x)
        e_rot = r.T @ orientation_error(self.force_hold_rot, self.arm.orientation())
        s = self.force_sel
        v_task = s * v + (1.0 - s) * FORCE_HOLD_RATE_PER_S * np.concatenate([e_pos, e_rot])
        self.force_v = s * v
        twist = np.concatenate([r @ v_task[:3], r @ v_task[3:]])
        return np.asarray(np.linalg.pinv(j) @ twist)

    def close(self) -> None:
        self.arm.close()

    def joint_torques(self) -> np.ndarray:
        """The motor torques of the last cycle beyond gravity compensation (N m)."""
        return np.array(self.tau_applied)
