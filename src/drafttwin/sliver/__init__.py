"""The sliver: from the rollers' speeds to the drawn sliver's evenness and its chimneys.

* :mod:`~drafttwin.sliver.staple`: the fibres (staple diagram, fineness, Martindale's limit);
* :mod:`~drafttwin.sliver.feed`: the doubled fed slivers and their faults;
* :mod:`~drafttwin.sliver.speeds`, :mod:`~drafttwin.sliver.physics`: the rollers' surface
  speeds, from records, predictions or the physics;
* :mod:`~drafttwin.sliver.drafting` (numba core in :mod:`~drafttwin.sliver.kernel`): the
  fibre-level drafting simulator;
* :mod:`~drafttwin.sliver.irregularity`, :mod:`~drafttwin.sliver.spectra`: count, CV %, U %,
  CV(L), the evenness tester's spectrogram with the ideal curve and its chimneys;
* :mod:`~drafttwin.sliver.transfer`, :mod:`~drafttwin.sliver.wavelengths`,
  :mod:`~drafttwin.sliver.attribution`: the drafting transfer, the machine's wavelength table
  and the element behind each chimney;
* :mod:`~drafttwin.sliver.sensor`: the drawframe's delivery and infeed sensors.

The package sits below the plant, diagnosis and the twin and imports only the mechanics and
the data layer.
"""

from drafttwin.sliver.attribution import Candidate, ChimneyCause, attribute
from drafttwin.sliver.diagnose import SliverDiagnosis, diagnose_sliver
from drafttwin.sliver.drafting import DraftingZones, RealDrafting, draft
from drafttwin.sliver.feed import Feed, FeedFault
from drafttwin.sliver.irregularity import Evenness, evenness
from drafttwin.sliver.record import Sliver, read_sliver
from drafttwin.sliver.spectra import Spectrogram, spectrogram
from drafttwin.sliver.speeds import SurfaceSpeeds
from drafttwin.sliver.staple import StapleDiagram
from drafttwin.sliver.wavelengths import Element, WavelengthTable, wavelength_table

draft_sliver = draft
"""The drafting simulator under the name the top-level API gives it (``dt.draft_sliver``)."""

__all__ = [
    "Candidate",
    "ChimneyCause",
    "DraftingZones",
    "Element",
    "Evenness",
    "Feed",
    "FeedFault",
    "RealDrafting",
    "Sliver",
    "SliverDiagnosis",
    "Spectrogram",
    "StapleDiagram",
    "SurfaceSpeeds",
    "WavelengthTable",
    "attribute",
    "diagnose_sliver",
    "draft",
    "draft_sliver",
    "evenness",
    "read_sliver",
    "spectrogram",
    "wavelength_table",
]
