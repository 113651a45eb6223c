"""The run layer: what the simulated episode (:mod:`evservo.sim.episode`) and the real loop
(:mod:`evservo.realloop`) share, so that the two loops are two clocks driving one set of pieces.

* :mod:`~evservo.runtime.metrics`: RMS, the camera's lag behind the target;
* :mod:`~evservo.runtime.watchdog`: one record of a watchdog spell;
* :mod:`~evservo.runtime.report`: ``summary.json``, ``log.csv`` and the Fig. 5 plot (``motion.png``);
* :mod:`~evservo.runtime.inputs`: resolving a run's inputs (camera geometry, object model, start pose);
* :mod:`~evservo.runtime.track`: open-loop tracking of a recording (``evservo track``).

Nothing here imports the simulator's scene (MuJoCo, the IK's QP): a hardware rig loads only what the
real loop needs.
"""
