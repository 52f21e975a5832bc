"""The browser viewer (viser) of the runtime pipeline; the only package that imports viser."""

from .app import ViewerApp, serve

__all__ = ["ViewerApp", "serve"]
