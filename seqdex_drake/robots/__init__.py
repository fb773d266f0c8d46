"""Robot descriptions: joint names and canonical order, limits, frames and named views.

`franka` describes the Franka Panda arm and `allegro` the Allegro right hand. Both are plain data modules; the
URDF files they describe are generated from them by `seqdex_drake.modeling.robot_models`.
"""
