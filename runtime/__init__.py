"""trioman.runtime: numpy + onnxruntime + OpenCV. Never imports torch.

Holds the math both sides need once: rotations, cameras, forward kinematics + LBS, the mesh
rasterizer, file formats and image/video I/O.
"""
