"""Every exported class and function of kexp has a docstring of its own: the names in each subpackage's
``__all__``, and the public classes and functions of the top-level modules (kexp.dictionary, kexp.errors).
A dataclass's generated "Name(field: type, ...)" text does not count, nor a docstring inherited from a base."""
import importlib
import inspect
import pkgutil

import pytest

import kexp

def exported() -> list[tuple[str, str, object]]:
    out = []
    for info in pkgutil.iter_modules(kexp.__path__):
        mod = importlib.import_module(f"kexp.{info.name}")
        if hasattr(mod, "__all__"):
            names = list(mod.__all__)
        elif info.ispkg:
            names = []
        else:  # a top-level module: what it defines
            names = [n for n, v in vars(mod).items() if not n.startswith("_")
                     and (inspect.isclass(v) or inspect.isfunction(v)) and v.__module__ == mod.__name__]
        for n in names:
            v = getattr(mod, n)
            if inspect.isclass(v) or inspect.isfunction(v):
                out.append((mod.__name__, n, v))
    return out


def own_docstring(obj) -> str:
    doc = obj.__dict__.get("__doc__") if inspect.isclass(obj) else obj.__doc__
    doc = (doc or "").strip()
    if inspect.isclass(obj) and doc.startswith(f"{obj.__name__}("):  # dataclass's generated signature
        return ""
    return doc


def test_the_walk_finds_the_exported_names():
    names = {f"{m}.{n}" for m, n, _ in exported()}
    assert len(names) >= 70
    assert {"kexp.recording.RunLogger", "kexp.simulate.closed_loop", "kexp.errors.KexpError",
            "kexp.dictionary.Monomials", "kexp.control.LmpcConfig"} <= names


@pytest.mark.parametrize("module,name,obj", exported(), ids=lambda v: v if isinstance(v, str) else "")
def test_every_exported_name_has_a_docstring(module, name, obj):
    doc = own_docstring(obj)
    assert len(doc) >= 20, f"{module}.{name} has no docstring of its own"


def test_a_missing_docstring_is_caught():
    from dataclasses import dataclass

    from kexp.errors import KexpError

    @dataclass
    class Bare:
        a: int

    class Child(KexpError):
        pass

    assert own_docstring(Bare) == "" and own_docstring(Child) == "" and own_docstring(lambda: 0) == ""
