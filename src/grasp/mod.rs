//! Task-specific arm configurations and robust grasps (paper eq. 10-29).
