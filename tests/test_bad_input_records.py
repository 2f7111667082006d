"""Bad floe record files: each refused naming the file, line and floe; a byte-order mark is read."""

import numpy as np
import pytest

from seaice_jax.drift.records import read_records
from seaice_jax.errors import SeaiceError

VALID = ("floe_id,time,image,pixel,scan,latitude,longitude\n"
         "F1,1983-03-08T14:00:00Z,IMG01,10,20,74.1,-84.0\n"
         "F1,1983-03-09T14:00:00Z,IMG02,11,21,74.2,-84.1\n")


@pytest.mark.parametrize(("text", "message"), [
    (VALID.replace("-84.1", "400"), r"records.csv, line 3: floe F1: position \(74.2, 400.0\) outside latitude"),
    (VALID.replace("74.1", "nan"), r"records.csv, line 2: floe F1: latitude is not finite"),
    (VALID.replace(",74.2,-84.1", ""), r"records.csv, line 3: floe F1: latitude None is not a number"),
    (VALID.replace("1983-03-09", "1983-03-07"), r"records.csv, line 3: floe F1: time .* is not after its previous"),
    (VALID.replace("IMG02", "IMG01"), r"records.csv, line 3: floe F1 appears twice in image IMG01"),
])
def test_bad_records_name_file_line_and_floe(tmp_path, text, message):
    path = tmp_path / "records.csv"
    path.write_text(text)
    with pytest.raises(SeaiceError, match=message):
        read_records(path)


def test_encodings_and_devices(tmp_path):
    path = tmp_path / "records.csv"
    path.write_bytes(b"\xef\xbb\xbf" + VALID.encode())
    np.testing.assert_allclose(np.degrees(read_records(path).latitude), [74.1, 74.2])
    path.write_bytes(VALID.replace("F1", "F\xe9").encode("latin-1"))
    with pytest.raises(SeaiceError, match=r"records.csv: not UTF-8 text"):
        read_records(path)
    with pytest.raises(SeaiceError, match=r": not a regular file"):
        read_records(tmp_path)


def test_collinear_floes_give_no_triangles_and_say_so_not_a_traceback():
    from seaice_jax.drift.kinematics import deformation

    points = np.stack([np.arange(4.0) * 1000.0, np.arange(4.0) * 2000.0], axis=1)
    rates = deformation(points, np.ones((4, 2)), 0.01)
    assert rates.note == "the 4 points lie on one line (or coincide): no triangles" and rates.triangles.shape == (0, 3)
