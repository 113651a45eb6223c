"""A franky-sim server for the Franka tests: the real franky client talking the libfranka protocol to a
MuJoCo FR3 served on a loopback address. Import only after checking ``franky_sim`` is installed."""

from __future__ import annotations

from franky_sim import SimulationServer
from franky_sim.mujoco_simulator import MujocoSimulator


class Sim:
    """A franky-sim server with one robot; picks a free 127.x.y.z address by itself."""

    def __init__(self) -> None:
        self.sim = MujocoSimulator(enable_visualization=False)
        self.sim.__enter__()
        self.sim.add_robot()
        self.server = SimulationServer(self.sim)
        self.server.__enter__()
        self.server.run_async()
        self.host = self.server.robot_servers[0].hostname

    def close(self) -> None:
        self.server.__exit__(None, None, None)
        self.sim.__exit__(None, None, None)
