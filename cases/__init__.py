"""The bundled scenes, one problem per file (``ngcontact list``).

In the source tree this is the top-level ``cases/`` directory; a wheel or ``pip install .`` ships it as
the package ``ngcontact.cases`` (``setup.py`` maps it), read by :func:`ngcontact.scenes.cases_dir`.
The files are examples to copy: a scene is problem data only (README, "Write your own scene").
"""
