"""The compiled per-tick arithmetic of dockhil.contact.rigid (dockhil/contact/_rigid.c); the rest is in
pyproject.toml.

Optional: where it does not build (no C compiler), dockhil runs its Python twin, which gives the
same numbers, more slowly."""

from setuptools import Extension, setup

# The same bits as the Python twin: no fused multiply-add, and sin/cos from the C library one by
# one (see the file's head).
FLAGS = ["-O2", "-ffp-contract=off", "-fno-builtin", "-fno-fast-math"]

setup(ext_modules=[Extension("dockhil.contact._rigid", ["dockhil/contact/_rigid.c"], extra_compile_args=FLAGS,
                             optional=True)])
