"""Plugin system: pluggy hook specifications and the plugin manager."""
from .hookspecs import hookimpl, hookspec
from .manager import get_plugin_manager, registry

__all__ = ["hookimpl", "hookspec", "get_plugin_manager", "registry"]
