from dualid.trajectories.trajectory import Trajectory

__all__ = ["Trajectory"]
