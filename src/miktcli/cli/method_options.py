"""A method's options on the command line, made from its pydantic options model (the one source of their
names, defaults, choices and help): each field is a flag, `--field-name VALUE`, or `--field/--no-field` for a
bool. `mikt transfer` leaves the flags it does not declare itself to this module, which reads them against
the chosen method's model; its help lists every method and its options, read from the registry when the
help is shown (importing the methods imports torch, which `mikt --help` and the other commands never need).
"""

from __future__ import annotations

import difflib
import typing

import annotated_types
import typer
from pydantic import BaseModel
from pydantic.fields import FieldInfo
from rich.markup import escape
from typer.core import TyperCommand

# How `mikt transfer` hands the flags it does not know to this module.
PASS_UNKNOWN_FLAGS = {"ignore_unknown_options": True, "allow_extra_args": True}


def flag_of(field: str) -> str:
    return "--" + field.replace("_", "-")


def _is_bool(info: FieldInfo) -> bool:
    return info.annotation is bool


def _flags(model: type[BaseModel]) -> dict[str, tuple[str, bool | None]]:
    """Every flag of a model: flag → (field, the value a bare bool flag sets; None for a flag taking a value)."""
    flags: dict[str, tuple[str, bool | None]] = {}
    for field, info in model.model_fields.items():
        if _is_bool(info):
            flags[flag_of(field)] = (field, True)
            flags["--no-" + field.replace("_", "-")] = (field, False)
        else:
            flags[flag_of(field)] = (field, None)
    return flags


def _option_models() -> dict[str, type[BaseModel]]:
    from miktcli.methods import METHODS

    return {name: m.options for name, m in METHODS.items() if m.for_transfer and m.options is not None}


def _unknown(flag: str, ctx: typer.Context) -> typer.BadParameter:
    known = [opt for p in ctx.command.params for opt in p.opts if opt.startswith("--")]
    known += [f for model in _option_models().values() for f in _flags(model)]
    close = difflib.get_close_matches(flag, known, n=1)
    return typer.BadParameter("no such option" + (f" (did you mean {close[0]}?)" if close else ""), ctx=ctx,
                              param_hint=f"'{flag}'")


def parse_method_options(ctx: typer.Context, method: str, options: type[BaseModel] | None) -> dict | None:
    """The options the user gave for `method` (field → value as typed; the model validates them later), or
    None for a method without options. A flag of another method, or of none, is a usage error: it would
    otherwise be silently ignored."""
    args = list(ctx.args)
    given: dict[str, object] = {}
    flags = _flags(options) if options is not None else {}
    while args:
        arg = args.pop(0)
        flag, has_value, value = arg.partition("=")
        if not flag.startswith("--"):
            raise typer.BadParameter("unexpected argument", ctx=ctx, param_hint=f"'{arg}'")
        if flag not in flags:
            elsewhere = {f: field for model in _option_models().values() for f, (field, _) in _flags(model).items()}
            if flag in elsewhere:
                raise typer.BadParameter(f"does not apply to --method {method}, which has no such option", ctx=ctx,
                                         param_hint=f"'{flag_of(elsewhere[flag])}'")
            raise _unknown(flag, ctx)
        field, bare = flags[flag]
        if bare is not None:
            if has_value:
                raise typer.BadParameter("takes no value", ctx=ctx, param_hint=f"'{flag}'")
            given[field] = bare
            continue
        if not has_value:
            if not args:
                raise typer.BadParameter("needs a value", ctx=ctx, param_hint=f"'{flag}'")
            value = args.pop(0)
        given[field] = value
    return given if options is not None else None


def _limits(info: FieldInfo) -> str:
    signs = {annotated_types.Ge: ("≥", "ge"), annotated_types.Gt: (">", "gt"), annotated_types.Le: ("≤", "le"),
             annotated_types.Lt: ("<", "lt")}
    return ", ".join(f"{sign} {getattr(meta, attr)}" for meta in info.metadata for kind, (sign, attr) in signs.items()
                     if isinstance(meta, kind))


def _option_line(field: str, info: FieldInfo) -> str:
    if _is_bool(info):
        name = f"{flag_of(field)} / --no-{field.replace('_', '-')}"
        default = "on" if info.default else "off"
    else:
        choices = typing.get_args(info.annotation) if typing.get_origin(info.annotation) is typing.Literal else ()
        kind = "|".join(map(str, choices)) if choices else getattr(info.annotation, "__name__", "VALUE").upper()
        name, default = f"{flag_of(field)} [{kind}]", str(info.default)
    limits = _limits(info)
    text = " ".join(filter(None, [info.description and info.description.rstrip(".") + ".",
                                  limits and f"{limits}.", f"Default: {default}."]))
    return f"{name}: {text}"


def methods_help() -> str:
    from miktcli.methods import METHODS

    return " | ".join(f"{name} ({m.summary}; KL weight {m.default_kl_coef:g})" for name, m in METHODS.items()
                      if m.for_transfer)


def options_help() -> str:
    """One paragraph per method option, under a heading per method that has options."""
    from miktcli.methods import METHODS

    paragraphs = []
    for name, m in METHODS.items():
        if m.for_transfer and m.options is not None:
            paragraphs.append(f"Options of --method {name} (in a study grid: options = {{ field = value }}):")
            paragraphs += [_option_line(field, info) for field, info in m.options.model_fields.items()]
    return "\n\n".join(escape(p) for p in paragraphs)


class MethodOptionsCommand(TyperCommand):
    """A command whose help lists the registry's methods (--method) and their options, when shown."""

    def format_help(self, ctx, formatter) -> None:
        for param in self.params:
            if param.name == "method":
                param.help = f"{escape(methods_help())}."
        from miktcli.cli.common import ppo_settings_help

        self.epilog = options_help() + "\n\n" + escape(ppo_settings_help())
        super().format_help(ctx, formatter)
