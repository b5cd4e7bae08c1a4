"""The release of skelfuse, defined once: the package metadata (pyproject.toml) and ``skelfuse.__version__``
read it here, and recordings name it in their header (docs/python-api.md, "Versioning")."""

__version__ = "0.1.0"
