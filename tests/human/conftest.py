"""Headless play: pygame's dummy video driver, matplotlib's Agg, no support prompt.

Set before pygame or matplotlib are imported (the Makefile exports the same).
"""

import os

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")
os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")

import pytest


@pytest.fixture
def pygame():
    """pygame with its display shut down again after the test (no window left open)."""
    import pygame

    yield pygame
    if pygame.display.get_init():
        pygame.event.set_grab(False)
    pygame.display.quit()


class FakeJoystick:
    """A pygame joystick stand-in: one per test, its axes set by the test."""

    def __init__(self, index=0, name="Test pad", axes=(0.0, 0.0), instance_id=7):
        self.index = index
        self.name = name
        self.axes = list(axes)
        self.instance_id = instance_id

    def get_name(self):
        return self.name

    def get_numaxes(self):
        return len(self.axes)

    def get_axis(self, i):
        return self.axes[i]

    def get_instance_id(self):
        return self.instance_id


@pytest.fixture
def fake_joystick(monkeypatch, pygame):
    """One FakeJoystick plugged in, as pygame.joystick sees it."""
    stick = FakeJoystick()
    monkeypatch.setattr(pygame.joystick, "get_count", lambda: 1)
    monkeypatch.setattr(pygame.joystick, "Joystick", lambda index: stick)
    return stick


@pytest.fixture
def no_joystick(monkeypatch, pygame):
    """No joystick plugged in, whatever the machine has."""
    monkeypatch.setattr(pygame.joystick, "get_count", lambda: 0)
