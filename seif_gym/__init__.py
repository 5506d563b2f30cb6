"""seif_gym: a Gymnasium environment for learning active SLAM with a SEIF in the loop."""

__version__ = "0.1.0"
