"""The farfield error hierarchy: one root, typed subclasses, and one table of how edges report them.

Every error raised on purpose by ``core`` derives from :class:`FarfieldError`.  Messages name the
offending values.  The HTTP API and the CLI map an error to a status or exit code through
:class:`ErrorKind`, so the mapping lives in exactly one place.

Most kinds blame the request (4xx, exit codes 2-6).  :class:`InternalError` (``INTERNAL``: HTTP 500,
exit code 1, what Python gives an uncaught exception) blames farfield itself: an invariant that the
code should guarantee was found broken, whatever the input.
"""

from __future__ import annotations

import enum


class ErrorKind(enum.Enum):
    """How an edge (HTTP, CLI) should report an error: (HTTP status, CLI exit code)."""

    BAD_INPUT = (422, 2)
    MISSING = (404, 3)
    CONFLICT = (409, 4)
    TOO_LARGE = (413, 2)
    RENDERER_UNAVAILABLE = (503, 5)
    UNAUTHORIZED = (401, 6)
    OVER_QUOTA = (429, 7)  # the caller has too much work in flight; the same request may pass later
    INTERNAL = (500, 1)  # a bug in farfield, never the caller's fault

    @property
    def http_status(self) -> int:
        return self.value[0]

    @property
    def exit_code(self) -> int:
        return self.value[1]


class FarfieldError(Exception):
    """Root of every error farfield raises on purpose."""

    kind: ErrorKind = ErrorKind.BAD_INPUT


class SceneLoadError(FarfieldError):
    """A scene file could not be read, parsed or validated."""


class SceneTooCostlyError(SceneLoadError):
    """A scene file whose structure (nodes, nesting, primitives, instanced triangles) is beyond the
    configured limits, refused before it is parsed in full."""

    kind = ErrorKind.TOO_LARGE


class SceneNotFoundError(SceneLoadError):
    """A scene file does not exist."""

    kind = ErrorKind.MISSING


class DegenerateGeometryError(FarfieldError):
    """Geometry with no extent, no triangles, or non-finite coordinates."""


class ViewCellError(FarfieldError):
    """A view cell that is malformed or that does not fit the represented part."""


class QueryError(FarfieldError):
    """A listing's or a query's parameter that names nothing the service has (an unknown job state, ...)."""


class UnknownTechniqueError(FarfieldError):
    """A technique name the registry does not hold (:func:`farfield.core.techniques.get_technique`):
    bad input (HTTP 422, exit code 2).

    >>> error_kind(UnknownTechniqueError("x")).value
    (422, 2)
    """


class LayerPlanError(FarfieldError):
    """Layer mathematics asked for a configuration that has no valid answer."""


class PlanBudgetError(LayerPlanError):
    """A layer plan stopped once it passed a caller's budget of texels (:func:`farfield.core.layering.plan.plan_layers`'s
    ``max_texels``): ``layers`` planned so far (the plan needs at least these) of ``texture`` texels.

    >>> error = PlanBudgetError(25, (3223, 3514))
    >>> error.texels, str(error)
    (283140550, 'the plan passed its budget of texels at 25 layers of 3223x3514')
    """

    def __init__(self, layers: int, texture: tuple[int, int]) -> None:
        super().__init__(f"the plan passed its budget of texels at {layers} layers of {texture[0]}x{texture[1]}")
        self.layers, self.texture = int(layers), (int(texture[0]), int(texture[1]))

    @property
    def texels(self) -> int:
        return self.layers * self.texture[0] * self.texture[1]


class AtlasOverflowError(FarfieldError):
    """Texels do not fit the allowed atlas pages."""


class JobTooCostlyError(FarfieldError):
    """A job whose estimated work (texels recorded, from its cells' layer plans) is beyond the
    configured limits per cell or per job.  TOO_LARGE (413), like an upload or a scene beyond its
    limits: the request is well formed and the same job passes on a service configured for more;
    the message gives the estimate, the limit and the setting that raises it."""

    kind = ErrorKind.TOO_LARGE


class QuotaError(FarfieldError):
    """A request refused because its tenant has too much work in flight (e.g. open cells); it may
    pass once some of that work ends (HTTP 429)."""

    kind = ErrorKind.OVER_QUOTA


class BusyError(QuotaError):
    """A request refused because the service is at capacity for that kind of work (e.g. every
    scene-check slot and queue place taken); the same request may pass in a few seconds (HTTP 429
    with a short ``Retry-After``)."""

    retry_after_s = 5


class AuthRateError(BusyError):
    """A client refused for a while after too many requests whose keys did not authenticate
    (HTTP 429; ``retry_after_s``: the seconds until it may try again)."""

    def __init__(self, message: str, retry_after_s: int = 60) -> None:
        super().__init__(message)
        self.retry_after_s = retry_after_s


class CellLimitError(FarfieldError):
    """A cell that ran past the worker's limit of time or memory per cell.  Bad input: the same cell
    would take as long or as much again, so it is failed, not retried."""


class ComparisonError(FarfieldError):
    """Impostors that cannot be compared side by side (other parts, cells or images), or none."""


class GuaranteeError(FarfieldError):
    """An impostor that breaks its promise from inside its view cell: a hole pixel, or a pixel
    bloated beyond one (``farfield evaluate --check``)."""

    kind = ErrorKind.CONFLICT


class BundleFormatError(FarfieldError):
    """An impostor bundle on disk is malformed or of an unknown version."""


class RenderBackendError(FarfieldError):
    """No usable rendering backend (EGL) in this process."""

    kind = ErrorKind.RENDERER_UNAVAILABLE


class NotFoundError(FarfieldError):
    """A stored scene, job, cell or key that does not exist (or belongs to another tenant)."""

    kind = ErrorKind.MISSING


class ConflictError(FarfieldError):
    """A request that the current state of a job or scene does not allow (e.g. retrying a done job)."""

    kind = ErrorKind.CONFLICT


class UploadTooLargeError(FarfieldError):
    """An upload over the configured size limit."""

    kind = ErrorKind.TOO_LARGE


class AuthError(FarfieldError):
    """A missing, unknown or revoked API key."""

    kind = ErrorKind.UNAUTHORIZED


class InternalError(FarfieldError):
    """An invariant farfield should guarantee was found broken: a bug, not bad input.

    >>> error_kind(InternalError("x")).http_status, error_kind(InternalError("x")).exit_code
    (500, 1)
    """

    kind = ErrorKind.INTERNAL


class ServiceConfigError(FarfieldError):
    """Settings that cannot work (a malformed URL, an unreadable data directory)."""


def error_kind(error: BaseException) -> ErrorKind:
    """The reporting kind of ``error``.

    >>> error_kind(LayerPlanError("x")).http_status
    422
    >>> error_kind(SceneNotFoundError("x")).exit_code
    3
    """
    if isinstance(error, FarfieldError):
        return error.kind
    raise TypeError(f"not a farfield error: {type(error).__name__}")
