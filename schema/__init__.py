"""The XVIZ v2 JSON Schema files, installed as package data of ``xviz_server``."""
