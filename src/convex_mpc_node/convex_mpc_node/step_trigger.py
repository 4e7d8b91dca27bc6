"""When the convex_mpc node runs a control step, and on which velocity. No rclpy: the node feeds it
the sensor messages (or their wire views) and /odom, and it calls back to control, to answer a
repeated step, and to publish the embedded estimator's /odom.

One control step per sensor step t_k, on the first of:
- /odom(t_k) (the estimator's output for t_k) once the joint state, IMU and contacts of t_k are in;
- with the estimator embedded: the step's three sensor messages (the filter updated here, before the
  command, or after it with ``estimate_after_command``, controlling on the previous step's estimate);
- a joint state (or IMU, contacts) of t_k with /odom older than ``input_timeout``: the stale path, on
  the backup estimator's velocity if there is one (a controlled stop; its last estimate holds
  BACKUP_HOLD over refused samples), else none (the supervisor's safe stance).
A step is controlled once: a joint state of a step already controlled (a lockstep bridge offering
the step again, or a duplicate) gets the same command again. Sensor time jumping back by more than
SIM_RESET_JUMP_NS is a simulation reset: the buffers and stamps start over (``on_restart``).
Stamps are integer nanoseconds of the messages' own clock.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from a1_interface.conversions import ns_from_stamp
from state_estimator_node.estimator import Estimate
from state_estimator_node.frontend import OdometryFrontend

BACKUP_HOLD = 0.02  # [s] the backup estimate outlives refused sensor samples this long
SIM_RESET_JUMP_NS = 100_000_000  # sensor time jumping back by more than this [ns] is a simulation reset
BUFFERED_STEPS = 50  # sensor steps kept per topic (0.1 s at 500 Hz)

Sensors = tuple[Any, Any, Any]  # one step's joint state, IMU and foot contacts
Control = Callable[[int, Sensors, "np.ndarray | None", "np.ndarray | None"], None]


class StepTrigger:
    """The stamp buffers and the stale / backup / embedded / duplicate paths of the control step.

    ``control(stamp_ns, sensors, velocity_world, backup_velocity)`` runs one step (velocities in the
    world frame [m/s], None when there is none); ``republish()`` sends the last command again;
    ``on_estimate(sensors, estimate)`` gets each embedded estimate after its step's command;
    ``on_restart()`` is called on a simulation reset; ``log(level, text, throttle)`` reports.
    """

    def __init__(self, *, input_timeout: float, frontend: OdometryFrontend | None, backup: OdometryFrontend | None,
                 estimate_after_command: bool, control: Control, republish: Callable[[], None],
                 on_estimate: Callable[[Sensors, Estimate], None], on_restart: Callable[[], None],
                 log: Callable[[str, str, bool], None]) -> None:
        self.input_timeout = input_timeout
        self.frontend = frontend
        self.backup = backup
        self.estimate_after_command = estimate_after_command and frontend is not None
        self._control, self._republish, self._on_estimate = control, republish, on_estimate
        self._on_restart, self._log = on_restart, log
        self.joints: dict[int, Any] = {}
        self.imu: dict[int, Any] = {}
        self.contacts: dict[int, Any] = {}
        self.odom_ns = -1
        self.controlled_ns = -1  # the last step a command was sent for
        self._odom_velocity = np.zeros(3)  # world frame [m/s], the last /odom's
        self.on_backup = False
        self._backup_sample: tuple[int, np.ndarray] | None = None  # (stamp, velocity) of its last estimate
        self._previous_velocity: np.ndarray | None = None  # world frame [m/s], the previous embedded estimate

    def latest_stamp_ns(self) -> int:
        return max(self.joints) if self.joints else 0

    # --- inputs ----------------------------------------------------------------------------------
    def on_joints(self, msg: Any) -> None:
        stamp_ns = self._store(self.joints, msg)
        if stamp_ns == self.controlled_ns:
            # The step again: a lockstep bridge offers it again while no command reached it (the
            # first one can be lost before DDS has matched the bridge), or a duplicate. Answer with
            # the command already computed: the controller must not step twice.
            self._republish()
            return
        self._sensor_in(stamp_ns)

    def on_imu(self, msg: Any) -> None:
        self._sensor_in(self._store(self.imu, msg))

    def on_contacts(self, msg: Any) -> None:
        self._sensor_in(self._store(self.contacts, msg))

    def on_odom(self, stamp_ns: int, velocity_world: np.ndarray) -> None:
        """/odom of step ``stamp_ns`` with its velocity (world frame [m/s])."""
        if not self._is_new_step(stamp_ns):  # late (its step went the stale way) or duplicated
            if stamp_ns > self.odom_ns:  # the estimator is alive: the next step waits for its /odom
                self.odom_ns, self._odom_velocity = stamp_ns, velocity_world
            return
        self.odom_ns, self._odom_velocity = stamp_ns, velocity_world
        if self.on_backup:
            self._log("info", "/odom is back", False)
            self.on_backup = False
        self._step(stamp_ns, velocity_world)

    # --- the paths ---------------------------------------------------------------------------------
    @staticmethod
    def _store(buffer: dict, msg: Any) -> int:
        stamp_ns = ns_from_stamp(msg.header.stamp)
        if buffer and stamp_ns < next(reversed(buffer)) - SIM_RESET_JUMP_NS:  # the last one stored
            buffer.clear()  # a sim reset: the old run's steps would evict the new run's (smaller) stamps
        buffer[stamp_ns] = msg
        while len(buffer) > BUFFERED_STEPS:
            del buffer[min(buffer)]
        return stamp_ns

    def _sensor_in(self, stamp_ns: int) -> None:
        if self.frontend is not None:
            self._estimate_and_step(stamp_ns)
        elif self._is_new_step(stamp_ns) and (stamp_ns - self.odom_ns) * 1e-9 > self.input_timeout:
            # No fresh /odom for this step: the backup estimate (controlled stop) or none (safe stance).
            self._step(stamp_ns, None, self._backup_velocity(stamp_ns))

    def _is_new_step(self, stamp_ns: int) -> bool:
        """``stamp_ns`` was not controlled yet. Time jumping back over SIM_RESET_JUMP_NS is a sim reset:
        start over, standing up first."""
        if stamp_ns < self.controlled_ns - SIM_RESET_JUMP_NS:
            self._log("warning", f"sensor time jumped back from {self.controlled_ns * 1e-9:.3f} s to "
                                 f"{stamp_ns * 1e-9:.3f} s: simulation reset; standing up again", False)
            self.controlled_ns = self.odom_ns = -1
            self._backup_sample, self.on_backup = None, False
            self._on_restart()
        return stamp_ns > self.controlled_ns

    def sensors(self, stamp_ns: int) -> Sensors | None:
        """This step's joint state, IMU and contacts, or None while one of them is not in."""
        joints, imu, contacts = self.joints.get(stamp_ns), self.imu.get(stamp_ns), self.contacts.get(stamp_ns)
        return None if joints is None or imu is None or contacts is None else (joints, imu, contacts)

    def _backup_velocity(self, stamp_ns: int) -> np.ndarray | None:
        """World-frame velocity from the backup estimator for a stale-/odom step, or None (no backup,
        no /odom yet to start it from, or its sensors refused for longer than BACKUP_HOLD)."""
        sensors = self.sensors(stamp_ns)
        if self.backup is None or self.odom_ns < 0 or sensors is None:
            return None
        if not self.on_backup:
            self._log("error", "/odom stale: stopping on the backup estimate, then a safe stance", False)
            self.backup.estimator.reset(self._odom_velocity)
            self.on_backup = True
            self._backup_sample = None
        estimate = self.backup.update(*sensors)
        if estimate is not None:
            self._backup_sample = (stamp_ns, estimate.velocity_world)
        elif self._backup_sample is None or (stamp_ns - self._backup_sample[0]) * 1e-9 > BACKUP_HOLD:
            return None  # one refused sample must not end the stop: the last estimate holds briefly
        return self._backup_sample[1]

    def _estimate_and_step(self, stamp_ns: int) -> None:
        """Embedded estimator: once this step's joints, IMU and contacts are all in, update the filter
        and control; a refused sample leaves the step (with ``estimate_after_command``: the next one)
        to the safe-stance path."""
        sensors = self.sensors(stamp_ns)
        if sensors is None or not self._is_new_step(stamp_ns):
            return
        if self.estimate_after_command:
            self._step(stamp_ns, self._previous_velocity)
        estimate = self.frontend.update(*sensors)
        self._previous_velocity = None if estimate is None else estimate.velocity_world
        if estimate is None:
            self._log("warning", "embedded estimator refused a sensor step (skew, joint names or NaN/inf)", True)
        else:
            self.odom_ns = stamp_ns
        if not self.estimate_after_command:
            self._step(stamp_ns, self._previous_velocity)
        if estimate is not None:  # after the command: off its path
            self._on_estimate(sensors, estimate)

    def _step(self, stamp_ns: int, velocity_world: np.ndarray | None,
              backup_velocity: np.ndarray | None = None) -> None:
        sensors = self.sensors(stamp_ns)
        if sensors is None:
            return  # this step's sensors are not all in (yet)
        self.controlled_ns = stamp_ns  # one command per step, whatever path and however often called
        self._control(stamp_ns, sensors, velocity_world, backup_velocity)
