"""The controller on a robot: the scenario split into a station and a controller that
talk over LCM (:mod:`stt_drake.robot.halves`, :mod:`stt_drake.robot.remote`), our
messages (:mod:`stt_drake.robot.stt_lcm`, generated from ``lcmtypes/``), the link's fault
handling and timing (:mod:`stt_drake.robot.transport`) and the runs
(:mod:`stt_drake.robot.session`)."""
