"""Example query plugins; :mod:`~citylod.semantics.plugins.tall_buildings` is the template for your own.

A query plugin is any object with ``name``, ``description`` and ``run(store, **params) -> list[str]``
(the :class:`citylod.semantics.queries.Query` protocol), exposed through the ``citylod.queries`` entry-point
group of your package::

    [project.entry-points."citylod.queries"]
    my_query = "my_package.my_module:MyQuery"
"""
