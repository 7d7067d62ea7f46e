"""File formats: sample tables, MERL binary BRDFs, raw images and their side-cars, Radiance
materials and PAB-Opto measurement files.

Each module reads and writes one format; writers go through :mod:`gonio.io.atomic`, so no
file is ever half-written. Nothing here runs an instrument or a campaign.
"""
