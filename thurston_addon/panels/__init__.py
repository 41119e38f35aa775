"""The add-on's panels and menus."""
from . import render

CLASSES = render.CLASSES
