"""Gymnasium environments of the VS-Wrist: one base environment (``base.VSWristEnv``), one module per task.

Make them with ``gymnasium.make("VSWrist/<Task>-v0")`` after ``import vswrist_gym``.
"""
