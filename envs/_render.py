"""The pygame window or RGB frame every environment's ``render`` shares.

An env holds ``_screen`` and ``_clock`` (None until the first render), declares
``metadata["render_fps"]`` and draws its display with ``_draw(canvas, pygame)``; these
two functions do the rest for ``render_mode`` ``"human"`` (a window) and
``"rgb_array"`` (a ``(height, width, 3)`` uint8 frame).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray

__all__ = ["close_window", "render_display"]


def render_display(env: Any, size: tuple[int, int]) -> NDArray[np.uint8] | None:
    """Draw ``env``'s display of ``size`` pixels: a frame, or None after showing it."""
    if env.render_mode is None:
        gym.logger.warn("render() called without a render_mode; pass render_mode= to the env")
        return None
    try:
        import pygame
    except ImportError as error:  # pragma: no cover - pygame is a dev dependency
        raise gym.error.DependencyNotInstalled(
            "rendering needs pygame: pip install 'manualcontrol[render]'"
        ) from error
    if env._screen is None:
        # display only: pygame.init() would also open the audio device
        if env.render_mode == "human":
            pygame.display.init()
            env._screen = pygame.display.set_mode(size)
            env._clock = pygame.time.Clock()
        else:
            env._screen = pygame.Surface(size)
    canvas = pygame.Surface(size)
    env._draw(canvas, pygame)
    if env.render_mode == "human":
        env._screen.blit(canvas, (0, 0))
        pygame.event.pump()
        pygame.display.flip()
        env._clock.tick(env.metadata["render_fps"])
        return None
    return np.transpose(np.array(pygame.surfarray.pixels3d(canvas)), (1, 0, 2)).copy()


def close_window(env: Any) -> None:
    """Close ``env``'s pygame window, if it opened one."""
    if env._screen is not None and env.render_mode == "human":
        import pygame

        pygame.display.quit()
    env._screen = None
