"""Headless rendering with moderngl on EGL: one context per process, small owners per resource kind."""
