"""Ctrl-C: never lost, never half a checkpoint.

Python turns SIGINT into a KeyboardInterrupt wherever the main thread is, and a library may swallow
it there (JAX's garbage-collection callback prints "Exception ignored" and goes on). :func:`catch`
remembers every SIGINT as well, so the run stops at its next check (:func:`raise_if_interrupted`,
after every training chunk and before the command returns). :func:`deferred` holds SIGINT back
while a checkpoint is written. While a run trains (:func:`graceful`), Ctrl-C and SIGTERM let the chunk
under way finish and be saved before it stops. Standard library only, so the CLI installs it before
importing JAX.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from typing import Iterator

_PRESSED = threading.Event()
_STOPPED_BY: list = []  # the signal :func:`graceful` took as a request to stop


def _on_sigint(signum, frame):
  _PRESSED.set()
  raise KeyboardInterrupt


def _unraisable(previous):
  def hook(unraisable):
    if not issubclass(unraisable.exc_type, KeyboardInterrupt):  # remembered, not printed
      previous(unraisable)
  return hook


def catch(pressed_before: bool = False) -> None:
  """From now on Ctrl-C raises KeyboardInterrupt as usual and is remembered, and one that lands where
  it cannot be raised (a finalizer, a gc callback) prints nothing; in the main thread.
  ``pressed_before``: Ctrl-C was pressed before (counts as pressed)."""
  _PRESSED.clear()
  _STOPPED_BY.clear()
  if pressed_before:
    _PRESSED.set()
  if threading.current_thread() is threading.main_thread():
    if signal.getsignal(signal.SIGINT) is not signal.SIG_IGN:  # a background job (nohup) keeps ignoring it
      signal.signal(signal.SIGINT, _on_sigint)
    if not getattr(sys.unraisablehook, "hdt", False):
      sys.unraisablehook = _unraisable(sys.unraisablehook)
      sys.unraisablehook.hdt = True


def pressed() -> bool:
  return _PRESSED.is_set()


def exit_code() -> int:
  """The shell's status for the signal that stopped the run: 130 (Ctrl-C), 143 (SIGTERM)."""
  return 128 + int(_STOPPED_BY[0] if _STOPPED_BY else signal.SIGINT)


def raise_if_interrupted() -> None:
  """KeyboardInterrupt if Ctrl-C was pressed since :func:`catch`, in case it was swallowed where it
  landed."""
  if _PRESSED.is_set():
    raise KeyboardInterrupt


@contextlib.contextmanager
def graceful() -> Iterator[None]:
  """Inside the block (a training loop that saves and stops when :func:`pressed` after each chunk),
  Ctrl-C and SIGTERM (a cluster's preemption) only ask it to stop, so the chunk under way is saved
  rather than lost; a second Ctrl-C stops at once. Main thread only; a signal the process ignores (a
  nohup job's SIGINT) stays ignored."""
  if threading.current_thread() is not threading.main_thread():
    yield
    return

  def ask(signum, frame):
    if _PRESSED.is_set():
      raise KeyboardInterrupt
    _STOPPED_BY[:] = [signum]
    _PRESSED.set()

  previous = {sig: signal.signal(sig, ask) for sig in (signal.SIGINT, signal.SIGTERM)
              if signal.getsignal(sig) is not signal.SIG_IGN}
  try:
    yield
  finally:
    for sig, handler in previous.items():
      signal.signal(sig, handler)


@contextlib.contextmanager
def deferred() -> Iterator[None]:
  """Ctrl-C (SIGINT) inside the block is held back until the block ends, so a checkpoint being
  written is finished rather than left half done (only in the main thread; elsewhere a no-op)."""
  if threading.current_thread() is not threading.main_thread():
    yield
    return
  caught = []
  previous = signal.signal(signal.SIGINT, lambda *a: caught.append(a))
  try:
    yield
  finally:
    signal.signal(signal.SIGINT, previous)
    if caught:
      if callable(previous):
        previous(*caught[0])
      else:
        os.kill(os.getpid(), signal.SIGINT)
