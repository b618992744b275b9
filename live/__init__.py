"""livecap: live human capture from depth cameras and motion-capture suits."""

__version__ = "0.1.0"
