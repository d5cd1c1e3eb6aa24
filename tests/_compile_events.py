"""Source text for the JIT tests' subprocess scripts: a numba compile listener that appends the qualified name of
each function numba compiles to the list ``compiled`` (numba's event API, ``numba:compile``)."""

LISTENER = '''
from numba.core import event

compiled = []


class Listener(event.Listener):
    def on_start(self, ev):
        pass

    def on_end(self, ev):
        compiled.append(ev.data["dispatcher"].py_func.__qualname__)


event.register("numba:compile", Listener())
'''
