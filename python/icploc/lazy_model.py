"""Typed settings classes whose pydantic validator is built, and pydantic imported, only when
a value is validated (:mod:`icploc.config` is made of them).

A class is written like a pydantic model: annotated fields with :func:`field` defaults, and
:func:`field_validator` / :func:`model_validator` methods. Its instances are plain objects
(``__dict__`` holds the values, in field order). Built with no values, an instance takes the
defaults without any validator (they are not validated field by field in pydantic either,
``validate_default`` being off) and runs only the class's ``_check`` model validator, if any.
Everything else -- construction with values, assignment, :meth:`LazyModel.model_validate` --
goes through the class's *twin*: a real pydantic model with the same name, fields, settings
and validators, built on first use (:meth:`LazyModel.pydantic_model`). Its
``ValidationError`` propagates as pydantic raises it, so the messages derived from it stay
those of a pydantic model; ``model_fields`` is the twin's.

Why: importing pydantic and creating the models costs a process ~70 ms of CPU (and more at
exit), which is most of what a replay with the default configuration does not need.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, ClassVar

if TYPE_CHECKING:
    from pydantic import BaseModel
    from typing_extensions import Self

__all__ = ["LazyModel", "field", "field_validator", "model_validator"]


class _Field:
    """A field's default (or default factory), description, unit and limits."""

    __slots__ = ("default", "factory", "doc", "unit", "limits")

    def __init__(
        self, default: Any, factory: Callable[[], Any] | None, doc: str, unit: str, limits: Any
    ) -> None:
        self.default, self.factory, self.doc, self.unit, self.limits = (
            default,
            factory,
            doc,
            unit,
            limits,
        )

    def make(self) -> Any:
        return self.factory() if self.factory is not None else self.default

    def pydantic(self) -> Any:
        from pydantic import Field

        extra: Any = {"unit": self.unit} if self.unit else None
        if self.factory is not None:
            return Field(default_factory=self.factory, description=self.doc or None)
        return Field(self.default, description=self.doc, json_schema_extra=extra, **self.limits)


def field(
    default: Any = None,
    doc: str = "",
    unit: str = "",
    *,
    default_factory: Callable[[], Any] | None = None,
    **limits: Any,
) -> Any:
    """A field: its default (or ``default_factory``), description, unit (m, rad, ...) and
    range (``gt`` / ``ge`` / ``lt`` / ``le``, as ``pydantic.Field`` takes them)."""
    return _Field(default, default_factory, doc, unit, limits)


class _Validator:
    """A validator method recorded for the twin; callable as the plain method it wraps."""

    __slots__ = ("kind", "fields", "mode", "func")

    def __init__(self, kind: str, fields: tuple[str, ...], mode: str, func: Any) -> None:
        self.kind, self.fields, self.mode, self.func = kind, fields, mode, func

    def __call__(self, *args: Any) -> Any:
        return self.func(*args)

    def pydantic(self) -> Any:
        from pydantic import field_validator as fv
        from pydantic import model_validator as mv

        if self.kind == "model":
            return mv(mode=self.mode)(self.func)  # type: ignore[call-overload]
        return fv(*self.fields, mode=self.mode)(self.func)  # type: ignore[call-overload]


def field_validator(*fields: str, mode: str = "after") -> Callable[[Any], Any]:
    """``pydantic.field_validator`` for a :class:`LazyModel` (applied to its twin)."""
    return lambda func: _Validator("field", fields, mode, func)


def model_validator(*, mode: str) -> Callable[[Any], Any]:
    """``pydantic.model_validator`` for a :class:`LazyModel` (applied to its twin); the
    ``_check`` one also runs on the defaults."""
    return lambda func: _Validator("model", (), mode, func)


class _ModelFields:
    """``cls.model_fields``: the twin's (pydantic ``FieldInfo`` by name)."""

    def __get__(self, obj: Any, cls: type[LazyModel]) -> Any:
        return cls.pydantic_model().model_fields


_BUILD_LOCK = threading.Lock()


class LazyModel:
    """Base of the lazily validated settings classes (see the module docstring)."""

    #: the twin's ``pydantic.ConfigDict`` settings
    model_settings: ClassVar[dict[str, Any]] = {}
    #: the fields, in order
    _fields: ClassVar[dict[str, _Field]] = {}
    _twin: ClassVar[Any] = None
    model_fields: ClassVar[Any] = _ModelFields()
    __hash__ = None  # type: ignore[assignment]  # mutable, compared by value (as pydantic's)

    def __init_subclass__(cls, **kw: Any) -> None:
        super().__init_subclass__(**kw)
        fields = dict(cls._fields)
        for name in cls.__dict__.get("__annotations__", {}):
            spec = cls.__dict__.get(name)
            if isinstance(spec, _Field):
                fields[name] = spec
                delattr(cls, name)  # as in pydantic: a field is no class attribute
        cls._fields = fields
        cls._twin = None

    # -- the twin --------------------------------------------------------------------------
    @classmethod
    def pydantic_model(cls) -> type[BaseModel]:
        """The pydantic model that validates this class's values (built on first use)."""
        twin = cls.__dict__.get("_twin")
        if twin is not None:
            return twin  # type: ignore[no-any-return]
        with _BUILD_LOCK:
            twin = cls.__dict__.get("_twin")
            if twin is None:
                twin = cls._build_twin()
                cls._twin = twin
        return twin  # type: ignore[no-any-return]

    @classmethod
    def _build_twin(cls) -> type[BaseModel]:
        from pydantic import BaseModel, ConfigDict

        ns: dict[str, Any] = {
            "__module__": cls.__module__,
            "__qualname__": cls.__qualname__,
            "__doc__": cls.__doc__,
            "model_config": ConfigDict(**cls.model_settings),  # type: ignore[typeddict-item]
        }
        own = [k for k in cls.__mro__ if issubclass(k, LazyModel) and k not in _BASES]
        anns: dict[str, Any] = {}
        for klass in reversed(own):
            for key, value in klass.__dict__.items():
                if key in ("_twin", "_fields", "model_settings"):
                    continue
                if key.startswith("__") and key.endswith("__"):
                    continue
                ns[key] = value.pydantic() if isinstance(value, _Validator) else value
            for key, ann in klass.__dict__.get("__annotations__", {}).items():
                if key in ("_twin", "_fields", "model_settings", "model_fields"):
                    continue
                if key in cls._fields or str(ann).startswith("ClassVar"):
                    anns[key] = ann
        ns["__annotations__"] = anns
        for name, spec in cls._fields.items():
            ns[name] = spec.pydantic()
        return type(cls.__name__, (BaseModel,), ns)

    # -- construction ----------------------------------------------------------------------
    def __init__(self, **data: Any) -> None:
        if not data:  # the defaults: no validator, only the class's own _check
            self.__dict__.update({k: f.make() for k, f in self._fields.items()})
            check = type(self).__dict__.get("_check")
            if check is None:
                return
            try:
                check(self)
                return
            except ValueError:
                self.__dict__.clear()  # the validated construction below words the error
        self.__dict__.update(self._validated(data).__dict__)

    @classmethod
    def _validated(cls, data: dict[str, Any]) -> BaseModel:
        """The twin built from ``data``; a ``ValidationError`` as :meth:`validation_error`
        words it."""
        model = cls.pydantic_model()
        try:
            return model(**data)
        except Exception as e:
            err = cls._reworded(e)
            if err is e:
                raise
            raise err from None

    @classmethod
    def validation_error(cls, e: Any) -> Exception:
        """The exception raised for pydantic's ``ValidationError`` ``e`` (itself; a
        subclass words it)."""
        return e  # type: ignore[no-any-return]

    @classmethod
    def _reworded(cls, e: Exception) -> Exception:
        from pydantic import ValidationError  # imported already: the twin exists

        return cls.validation_error(e) if isinstance(e, ValidationError) else e

    @classmethod
    def model_validate(cls, data: dict[str, Any]) -> Self:
        """An instance from a mapping, always through the validator (also for no values)."""
        obj = cls.__new__(cls)
        obj.__dict__.update(cls._validated(dict(data)).__dict__)
        return obj

    def model_copy(self, update: dict[str, Any] | None = None) -> Self:
        """A shallow copy with some values changed, *not* validated (as pydantic's)."""
        obj = type(self).__new__(type(self))
        obj.__dict__.update(self.__dict__)
        obj.__dict__.update(update or {})
        return obj

    def __setattr__(self, name: str, value: Any) -> None:
        """Validated assignment (the twin's ``validate_assignment``)."""
        twin = type(self).pydantic_model().model_construct(**self.__dict__)
        try:
            setattr(twin, name, value)
        except Exception as e:
            err = type(self)._reworded(e)
            if err is e:
                raise
            raise err from None
        self.__dict__.update(twin.__dict__)

    def __eq__(self, other: object) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        return self.__dict__ == other.__dict__

    def __repr__(self) -> str:
        return f"{type(self).__name__}(" + ", ".join(
            f"{k}={v!r}" for k, v in self.__dict__.items()
        ) + ")"


_BASES = (LazyModel,)
