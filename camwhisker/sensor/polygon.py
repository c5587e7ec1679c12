"""Area and centroid of closed image polygons (shoelace formula), and the
centroid's derivative.

A projected rim is such a polygon: the magnifier tip's model position is the
area centroid of its end face's projected rim (the projection of a disc's
centre is not its image's centroid), and the tip measured in a frame is the
centroid of the fitted rim.
"""

from camwhisker.kernels.polygon import polygon_area, polygon_centroid, polygon_centroid_jacobian

__all__ = ["polygon_area", "polygon_centroid", "polygon_centroid_jacobian"]
