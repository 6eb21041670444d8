"""City models: the model (:mod:`.model`), its readers (CityGML, CityJSON) and the dispatcher (:mod:`.read`)."""

from citylod.io.city.model import CityModel, CityObject, orient_outward, repair_polygon, to_metric
from citylod.io.city.read import read_city_model

__all__ = ["CityModel", "CityObject", "orient_outward", "read_city_model", "repair_polygon", "to_metric"]
