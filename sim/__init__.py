"""The sensor simulator: scenes of emitting triangle meshes, a Tango-like ToF + colour device, device
trajectories and ground truth. Deterministic from a seed. Only ``sim`` and ``apps`` know this package;
the pipeline library (``rgbd_envmap``) only sees the packets it produces."""
