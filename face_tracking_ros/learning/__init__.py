"""Learning the face model from 3-D meshes: alignment (§3.3), §3.4 and joint learners.

:mod:`face_tracking_ros.pipelines.learn` runs them on bags (``face-tracking learn``, the learner
node).
"""
