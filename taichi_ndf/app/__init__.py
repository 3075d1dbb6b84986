"""A scene run with its outputs: the application layer's library part."""
