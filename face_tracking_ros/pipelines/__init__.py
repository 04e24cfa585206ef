"""Bag pipelines: offline runs that read bags, replay trackers over them and write results.

:mod:`.learn` learns a face model from bags of meshes or raw stereo images (``face-tracking
learn``, the learner node), with its options (:mod:`.learn_options`), its reading of a bag's
meshes (:mod:`.mesh_bags`) and its tracking of raw stereo bags (:mod:`.stereo_meshes`);
:mod:`.bag_inputs` (a tracker replay's inputs and parameters) and :mod:`.scoring` (a tracked
bag against its truth) hold what that tracking shares with ``face-tracking track``. Like
:mod:`face_tracking_ros.replay`, they sit above the algorithms and :mod:`face_tracking_ros.io`
(bags and message types); the command line and the nodes call them.
"""
