"""City objects, proxies, the feature state store, queries and their plugin registry. No VTK, no Qt."""
