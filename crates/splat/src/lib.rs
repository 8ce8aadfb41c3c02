//! Differentiable 3D Gaussian splatting on the CPU: RGB-D render, gradients, Fisher information.
