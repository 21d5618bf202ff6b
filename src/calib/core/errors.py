"""Errors a user can cause, and the exit codes of the ``calib`` command line.

Every refusal names what is wrong where, and how to fix it::

    calib CMD: error: FILE: FIELD: what (fix: ...)

* :class:`InputError` (exit 2): bad input, configuration or environment -- a file that breaks the recording
  format, a settings key of the wrong type, an implausible magnitude for the declared units, an output
  folder that does not exist. It is also a ``ValueError``, so code that catches ``ValueError`` keeps working.
* :class:`ResultCheckError` (exit 3): the computation ran, but its result failed its own sanity checks (an
  implausible calibration, a non-finite navigation solution).
* :class:`Terminated` (exit 128 + signal): SIGTERM raised as an exception; it is a ``KeyboardInterrupt``, so
  every clean-up path that handles Ctrl-C (the atomic writers) handles it alike.

The exit-code contract of the command line (``calib --help``, README "Exit codes") is :data:`EXIT_CODES`.
:func:`load_mapping` and :func:`schema_error` turn what YAML, JSON and JSON-schema parsers raise into an
:class:`InputError` naming the file, the line and the key path.
"""
from __future__ import annotations

import json
import os
import signal
from pathlib import Path

import yaml

EXIT_OK = 0
EXIT_MISSING_PHYSICS = 1
EXIT_INPUT = 2
EXIT_RESULT = 3
EXIT_INTERNAL = 70
EXIT_SIGINT = 128 + int(signal.SIGINT)     # 130
EXIT_SIGTERM = 128 + int(signal.SIGTERM)   # 143
EXIT_SIGPIPE = 128 + int(getattr(signal, "SIGPIPE", 13))   # 141, as a shell reports a command its pipe's reader left

#: the contract, in the words the command line prints
EXIT_CODES = (
    (EXIT_OK, "success (diagnose: the model is adequate)"),
    (EXIT_MISSING_PHYSICS, "diagnose: missing physics found and explained"),
    (EXIT_INPUT, "usage error or bad input, configuration or environment; no earlier output is replaced"),
    (EXIT_RESULT, "diagnose: inconclusive; any command: its result failed its own sanity checks (written for "
                  "inspection, the message names the setting to change)"),
    (EXIT_INTERNAL, "internal error: one line on the terminal, the traceback in a log file"),
    (EXIT_SIGINT, "interrupted by SIGINT (Ctrl-C); no partial output is left"),
    (EXIT_SIGTERM, "terminated by SIGTERM; no partial output is left"),
    (EXIT_SIGPIPE, "the reader of standard output went away (e.g. '| head'): stopped there, silently; no partial "
                   "output is left"),
)


class CalibError(Exception):
    """A refusal with the file, the field, what is wrong and the fix; ``exit_code`` for the command line."""

    exit_code = EXIT_INPUT

    def __init__(self, message: str, file=None, field=None, fix=None, exit_code: int | None = None):
        self.message = str(message)
        self.file = None if file is None else str(file)
        self.field = None if field is None else str(field)
        self.fix = fix or None
        if exit_code is not None:
            self.exit_code = int(exit_code)
        super().__init__(self.text())

    def text(self) -> str:
        """``FILE: FIELD: what (fix: ...)``, leaving out the parts that are not known."""
        parts = [p for p in (self.file, self.field) if p]
        out = ": ".join(parts + [self.message])
        return f"{out} (fix: {self.fix})" if self.fix else out


class InputError(CalibError, ValueError):
    """Bad input, configuration or environment (exit 2)."""

    exit_code = EXIT_INPUT


class ResultCheckError(CalibError):
    """A result that failed its own sanity checks (exit 3); the result may have been written for inspection."""

    exit_code = EXIT_RESULT


class Terminated(KeyboardInterrupt):
    """A termination signal (SIGTERM) turned into the same clean path as Ctrl-C; exit 128 + the signal."""

    def __init__(self, signum: int = int(signal.SIGTERM)):
        self.signum = int(signum)
        self.exit_code = 128 + self.signum
        super().__init__(f"terminated by signal {self.signum}")


# --------------------------------------------------------------------------- files and settings a user gives


def input_file(path, what: str = "input file") -> Path:
    """``path`` as a readable file, or an :class:`InputError` (not found, a folder, not readable)."""
    p = Path(path)
    if not p.exists():
        raise InputError(f"{what} not found", file=p)
    if p.is_dir():
        raise InputError(f"is a folder, not a {what}", file=p, fix=f"give the path of the {what}")
    if not os.access(p, os.R_OK):
        raise InputError("permission denied", file=p, fix="make the file readable")
    return p


def yaml_problem(exc) -> str:
    """What is wrong in a YAML text, without PyYAML's multi-line context."""
    return f"malformed YAML: {getattr(exc, 'problem', None) or str(exc).splitlines()[0]}"


def yaml_line(text: str, keys) -> int | None:
    """Line (1-based) of the key path ``keys`` (mapping keys and sequence indices) in a YAML text, or None."""
    try:
        node = yaml.compose(text)
    except yaml.YAMLError:
        return None
    line = None
    for k in keys:
        if isinstance(node, yaml.MappingNode):
            hit = [(kn, vn) for kn, vn in node.value if kn.value == str(k)]
            if not hit:
                break
            line, node = hit[0][0].start_mark.line + 1, hit[0][1]
        elif isinstance(node, yaml.SequenceNode) and isinstance(k, int) and k < len(node.value):
            node = node.value[k]
            line = node.start_mark.line + 1
    return line


def load_mapping(path, what: str = "settings file") -> dict:
    """A YAML (or, by suffix, JSON) file holding a mapping; an empty file is ``{}``. Malformed files are refused
    with the file and the line of the error."""
    p = input_file(path, what)
    try:
        text = p.read_text()
    except UnicodeDecodeError:
        raise InputError(f"not a text {what}", file=p) from None
    try:
        data = json.loads(text) if p.suffix == ".json" else yaml.safe_load(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"malformed JSON: {exc.msg}", file=p, field=f"line {exc.lineno}") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        raise InputError(yaml_problem(exc), file=p, field=f"line {mark.line + 1}" if mark else None) from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise InputError(f"a {what} must be a mapping of keys to values, not {type(data).__name__}", file=p)
    return data


def _allowed(schema: dict) -> str:
    """The allowed type and range of a JSON-schema node, in a few words."""
    parts = []
    if "enum" in schema:
        parts.append("one of " + ", ".join(map(str, schema["enum"])))
    if "type" in schema:
        parts.append(schema["type"] if isinstance(schema["type"], str) else " or ".join(schema["type"]))
    for key, op in (("minimum", ">="), ("exclusiveMinimum", ">"), ("maximum", "<="), ("exclusiveMaximum", "<"),
                    ("minItems", "items >="), ("maxItems", "items <="), ("minLength", "length >=")):
        if key in schema:
            parts.append(f"{op} {schema[key]}")
    if "pattern" in schema:
        parts.append(f"matching {schema['pattern']}")
    return " ".join(parts)


def schema_error(data, schema: dict, path, text: str = "", schema_name: str = "the schema") -> InputError | None:
    """The best-matching JSON-schema error of ``data`` (``jsonschema.exceptions.best_match``) as an
    :class:`InputError` naming the key path, its line in ``text`` and what is allowed -- never the schema dump.
    None when ``data`` is valid."""
    import jsonschema

    validator = jsonschema.validators.validator_for(schema)(schema)
    err = jsonschema.exceptions.best_match(validator.iter_errors(data))
    if err is None:
        return None
    keys = list(err.absolute_path)
    msg = err.message if len(err.message) <= 160 else err.message[:157] + "..."
    allowed = _allowed(err.schema) if isinstance(err.schema, dict) else ""
    if err.validator == "additionalProperties" and isinstance(err.instance, dict):
        known = err.schema.get("properties", {})
        extra = sorted(set(err.instance) - set(known))
        if extra:
            keys.append(extra[0])
            msg = f"unknown key '{extra[0]}'"
        allowed = "keys " + ", ".join(sorted(known))
    elif err.validator == "required":
        allowed = "required keys " + ", ".join(err.schema.get("required", []))
    key = ".".join(map(str, keys)) or "(top level)"
    line = yaml_line(text, keys) if text else None
    return InputError(msg + (f"; allowed: {allowed}" if allowed else ""), file=path,
                      field=key + (f" (line {line})" if line else ""), fix=f"correct '{key}' ({schema_name})")


def fill_schema_defaults(data: dict, schema: dict) -> dict:
    """``data`` with every ``default`` of ``schema`` filled in where the key is absent, in place (and returned).

    The same rule as the workflow's ``snakemake.utils.validate(config, schema)``: the recipe of the jsonschema
    documentation (a ``properties`` validator extended to set the defaults of absent keys before it validates
    them), so a config read by the ``calib`` command and by the workflow gets the same values. Without snakemake:
    the library and its command line do not need the workflow's dependencies."""
    import jsonschema

    base = jsonschema.validators.validator_for(schema)
    set_props = base.VALIDATORS["properties"]

    def properties(validator, props, instance, sub):
        if isinstance(instance, dict):
            for name, subschema in props.items():
                if isinstance(subschema, dict) and "default" in subschema:
                    instance.setdefault(name, subschema["default"])
        yield from set_props(validator, props, instance, sub)

    filler = jsonschema.validators.extend(base, {"properties": properties})
    filler(schema).validate(data)
    return data
