"""Ingest: the sensor packets of a frame → an RGB-D frame. :mod:`rgbd_envmap.ingest.tango`: a ToF
point cloud and an NV21 colour image (paper 003 §4.1); :mod:`rgbd_envmap.ingest.kinect`: warp and
merge of registered Kinect depth (paper 001 §4.2).
"""
