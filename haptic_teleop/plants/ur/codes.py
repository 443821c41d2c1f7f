"""A UR controller's status codes as RTDE reports them, with what each means for a session and
what to do: robot mode, safety mode and its status bits, the joints' modes (docs/ur_protocols.md, "Status
codes"; Universal Robots' RTDE guide and dashboard server documentation)."""

from __future__ import annotations

ROBOT_MODE = {-1: "NO_CONTROLLER", 0: "DISCONNECTED", 1: "CONFIRM_SAFETY", 2: "BOOTING", 3: "POWER_OFF",
              4: "POWER_ON", 5: "IDLE", 6: "BACKDRIVE", 7: "RUNNING", 8: "UPDATING_FIRMWARE"}  # fmt: skip
SAFETY_MODE = {1: "NORMAL", 2: "REDUCED", 3: "PROTECTIVE_STOP", 4: "RECOVERY", 5: "SAFEGUARD_STOP",
               6: "SYSTEM_EMERGENCY_STOP", 7: "ROBOT_EMERGENCY_STOP", 8: "VIOLATION", 9: "FAULT",
               10: "VALIDATE_JOINT_ID", 11: "UNDEFINED_SAFETY_MODE", 12: "AUTOMATIC_MODE_SAFEGUARD_STOP",
               13: "SYSTEM_THREE_POSITION_ENABLING_STOP"}  # fmt: skip
SAFETY_BIT_PROTECTIVE = 1 << 2
SAFETY_BITS_EMERGENCY = (1 << 5) | (1 << 6) | (1 << 7)
RUNNING = 7
# What to do after each safety stop but the protective and emergency ones (their own messages below).
SAFETY_STOP_WHAT_TO_DO = {
    5: "a safeguard stop input opened (a door, a light curtain, a safety mat): clear it and reset it",
    8: "a safety limit was violated (a joint position or speed, the TCP, the power): read the log on the teach "
    "pendant, move the arm back within the limits",
    9: "a safety system fault: read the log on the teach pendant, then restart the controller",
    12: "the automatic mode safeguard stop input opened: clear it and reset it",
    13: "the three-position enabling device was released or pressed through: hold it in the middle position",
}
# RTDE joint_mode [RTDE guide, "joint_mode"; docs/ur_protocols.md]: name and, for a joint not running, what to do.
JOINT_RUNNING = 253
JOINT_MODE = {
    235: ("RESET", "the joint is resetting: wait for it, then power on"),
    236: ("SHUTTING_DOWN", "the joint is shutting down: power the arm on again"),
    237: ("PART_D_CALIBRATION", "the joint is calibrating: wait for it, then start again"),
    238: ("BACKDRIVE", "the arm is in backdrive mode: leave it on the teach pendant and release the brakes"),
    239: ("POWER_OFF", "the joint is not powered: power the arm on and release the brakes"),
    240: ("READY_FOR_POWER_OFF", "the joint is being powered off: power the arm on again"),
    245: ("NOT_RESPONDING", "the joint does not answer the controller: read the log, power-cycle the arm"),
    246: ("MOTOR_INITIALISATION", "the joint's motor is starting: wait for it, then start again"),
    247: ("BOOTING", "the joint is booting: wait for it, then start again"),
    248: ("PART_D_CALIBRATION_ERROR", "the joint's calibration failed: read the log on the teach pendant"),
    249: ("BOOTLOADER", "the joint is in its bootloader (a firmware update): let it finish"),
    250: ("CALIBRATION", "the joint is calibrating: wait for it, then start again"),
    251: ("VIOLATION", "the joint violated a safety limit: read the log on the teach pendant"),
    252: ("FAULT", "a joint fault: read the log on the teach pendant, then power-cycle the arm"),
    253: ("RUNNING", ""),
    255: ("IDLE", "the joint is not under control and its brake holds it: release the brakes on the teach pendant "
          "once the log says why they engaged"),
}  # fmt: skip
