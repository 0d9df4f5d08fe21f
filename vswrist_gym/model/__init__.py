"""The MuJoCo model of the VS-Wrist, generated from a parameter set (see ``builder``)."""

from .builder import build_model, build_spec, export_xml, model_xml

__all__ = ["build_model", "build_spec", "export_xml", "model_xml"]
