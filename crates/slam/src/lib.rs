//! RGB-D Gaussian-splatting SLAM: tracking and mapping without ground-truth poses.
