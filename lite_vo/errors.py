"""The project's exceptions. Library code raises these; the CLI prints ``str(err)`` as one line."""


class LiteVOError(Exception):
    """Base class: a problem the user can fix (bad input, bad configuration, missing extra)."""


class ConfigError(LiteVOError):
    """A profile or override is invalid (unknown key, wrong type, out of range)."""


class InputError(LiteVOError):
    """A sequence, calibration, trajectory or image is missing, unreadable or inconsistent."""


class MissingExtraError(LiteVOError):
    """An optional dependency (e.g. the ``[ar]`` extra) is not installed."""


class Interrupted(BaseException):
    """Raised in the main thread by the SIGTERM handler the CLI installs (SIGINT is KeyboardInterrupt);
    like KeyboardInterrupt it is no Exception, so nothing on the way catches it by accident."""

    def __init__(self, signum: int) -> None:
        super().__init__(f"signal {signum}")
        self.signum = signum
