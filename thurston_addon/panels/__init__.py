"""The add-on's panels and menus."""

from . import render_properties

CLASSES = render_properties.CLASSES
