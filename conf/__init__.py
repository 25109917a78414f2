"""Hydra config tree (pkg://arcsem.conf). Importing it registers the config schemas (:mod:`arcsem.schemas`)."""
from arcsem.schemas import setup

setup()
