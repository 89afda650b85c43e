"""Plugin system: pluggy hook specifications and the plugin manager."""
from softsbi.plugins.hookspecs import hookimpl, hookspec
from softsbi.plugins.manager import Registry, check_options, get_plugin_manager, registry

__all__ = ["Registry", "check_options", "get_plugin_manager", "hookimpl", "hookspec", "registry"]
