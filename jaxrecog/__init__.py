"""jaxrecog: active multi-camera object recognition and pose estimation in JAX.

The method is the thesis "Robust Sequential View Planning for Object Recognition
Using Multiple Cameras": eigenspace features per camera position, occlusion-aware
Gaussian sensor models, a recursive Bayesian belief over (object, pose, occlusion
level per camera), and view planning over all camera configurations by Mutual
Information or a Cramér-Rao bound.
"""

__version__ = "0.1.0"
