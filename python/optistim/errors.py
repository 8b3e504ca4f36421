"""The exceptions optistim raises; their messages are the CLI's."""


class OptistimError(Exception):
    """Base of every optistim error."""


class SceneError(OptistimError, ValueError):
    """A scene file or dict that does not validate (the message names the file, key, value
    and what is allowed)."""


class PoseError(OptistimError, ValueError):
    """A pose that is not one: wrong number of values, a non-finite value, a quaternion off
    unit norm, or a pose file that cannot be read."""


class RenderError(OptistimError, RuntimeError):
    """A frame that could not be rendered (the camera inside the body, a memory guard) or
    written."""
