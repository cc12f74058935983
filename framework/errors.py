"""Errors a user can fix. The command line prints their message as one line and exits non-zero."""


class UserError(Exception):
    """Bad input or environment; the message says what is wrong and how to fix it."""


class SceneError(UserError):
    """A scene directory that does not follow the scene format (docs/scene-format.md)."""


class ConfigError(UserError):
    """A configuration value outside its allowed range."""


class EnvironmentSetupError(UserError):
    """The machine lacks something the renderer needs (for example a usable libLLVM)."""
