"""Calibrating the rig from events: intrinsics from a blinking checkerboard, hand-eye from arm poses.

Modules, bottom up: :mod:`~evservo.calib.board` (the checkerboard and its detection in an image),
:mod:`~evservo.calib.blinks` (splitting a recording into blinks and event images),
:mod:`~evservo.calib.views` (detected boards grouped into still views),
:mod:`~evservo.calib.intrinsics`, :mod:`~evservo.calib.handeye`, :mod:`~evservo.calib.camfile`
(the files written) and :mod:`~evservo.calib.capture` (recording views on a real rig).
"""
