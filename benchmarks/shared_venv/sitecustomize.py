"""Run another checkout of arcsem with this checkout's virtual environment (an editable install), for side-by-side
benchmarks of two commits without a second ``make setup``::

    git worktree add /tmp/base <commit>
    ARCSEM_ROOT=/tmp/base PYTHONPATH=benchmarks/shared_venv .venv/bin/python ...   # imports /tmp/base's arcsem

With ``ARCSEM_ROOT`` set, the editable install's import finder (setuptools' ``__editable___arcsem_*_finder``, loaded by
its ``.pth`` file before this module) maps ``arcsem``, ``arcsem.backbones``, ``arcsem.losses`` and ``arcsem.conf``
to that tree instead of this one. ``benchmarks/step_ab.py --shared-venv`` sets both variables for each tree.
"""
import os
import sys

_root = os.environ.get("ARCSEM_ROOT")
if _root:
    _finders = [m for n, m in list(sys.modules.items())
                if n.startswith("__editable___arcsem") and n.endswith("_finder") and hasattr(m, "MAPPING")]
    _here = next((os.path.dirname(m.MAPPING["arcsem"]) for m in _finders if "arcsem" in m.MAPPING), None)
    for _module in _finders if _here else ():  # every package installed from this checkout, the examples' too
        for _key, _path in list(_module.MAPPING.items()):
            if os.path.commonpath([_path, _here]) == _here:
                _module.MAPPING[_key] = os.path.join(_root, os.path.relpath(_path, _here))
