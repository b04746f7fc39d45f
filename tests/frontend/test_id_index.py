import numpy as np

from zenslam.frontend.id_index import IdIndex


def test_rows_of_ids_added_in_batches_match_a_dict():
    rng = np.random.default_rng(3)
    ids = rng.choice(2**62 + np.arange(5000, dtype=np.int64), size=3000, replace=False)
    ids[:1000] = np.arange(1000)  # two id spaces, as frontend and backend use
    truth = {}
    index = IdIndex()
    for start in range(0, 3000, 700):
        batch = ids[start : start + 700]
        rows = np.arange(start, start + len(batch))
        index.add(batch, rows)
        truth.update(zip(batch.tolist(), rows.tolist()))
    queries = np.concatenate([ids, [-1, 1001, 2**62 - 1, 2**63 - 1]])
    expected = [truth.get(int(i), -1) for i in queries]
    assert index.rows(queries).tolist() == expected
    assert len(index) == 3000


def test_empty_index_and_shapes():
    index = IdIndex()
    assert index.rows(np.array([[0, 5]])).tolist() == [-1, -1]
    index.add(np.array([], dtype=np.int64), np.array([], dtype=np.int64))
    assert len(index) == 0
