"""The package version, here in core/ so that core (io.py's output markers) need not import the
package root (DESIGN: core imports nothing of ours); poevp_optics.__version__ re-exports it.
Keep equal to pyproject.toml's `version`."""

__version__ = "0.2.0"
