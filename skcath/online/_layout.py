"""Named layout of the arrays of one packed streaming step, and their packing.

:func:`~skcath.online._kernels.step` reads everything it needs about a run
from six arrays made once by :class:`PackedStep` when the run starts:

* ``meta`` (int64): the header ``M_*`` (kinds, sizes, offsets into ``buf``),
  then one record per GRU layer (``GRU_*``) and one per layer of the head
  (``HEAD_*``), each holding matrix records (``MAT_*``);
* ``f`` (float64): the nominal tip of the last step, the clip and the
  half-width of the play operator in front of the backbone (0 without
  hysteresis, negative for the Prandtl-Ishlinskii hysteresis), the square of
  the motor range accepted and the time since the previous step (``F_*``); then,
  sized by the number of motors ``N`` at the offsets ``meta[M_LAST]``,
  ``meta[M_PLAY]``, ``meta[M_ANGLES]``: the last accepted sample ``(q1 ..
  qN, tau1 .. tauN)`` (``N`` values without torques), the state of the play
  (``N``) and the motor angles the backbone reads (``N``); then the
  neutral motor angles (``N``) at ``meta[M_NEUTRAL]``; with the
  Prandtl-Ishlinskii hysteresis its packed parameters
  (:meth:`~skcath.backbones.PrandtlIshlinskii.pack`) at ``meta[M_PI_THETA]``,
  its dead band up then down (``N`` each) at ``meta[M_PI_BANDS]`` and its
  state (``K + 2`` per motor, :func:`~skcath.backbones.pi_step`) at
  ``meta[M_PI_STATE]``;
* ``theta`` (float64): the backbone's packed parameters
  (:meth:`~skcath.backbones.PCCParams.pack`,
  :meth:`~skcath.backbones.PDLParams.pack`,
  :meth:`~skcath.backbones.PolynomialParams.pack`);
* ``w`` and ``w32``: the weight matrices (see :class:`FlatStore` and
  :class:`MatrixStore`);
* ``buf`` (the network's dtype): the per-layer vectors ``[x; 1; h]`` that
  hold the GRU's hidden states, the gates, the head's vectors ``[1; a]``,
  the residual (3,) and a scratch vector.

Every offset the step reads is named here, once; every size that depends on
the number of motors is set here, by :class:`PackedStep`.
"""

from __future__ import annotations

import numpy as np

from .._kernel import kernel, offsets

__all__ = ["FlatStore", "MatrixStore", "PackedStep", "PI_FLAG", "without_hysteresis"]

# kinds of backbone and residual (meta[M_BACKBONE], meta[M_RESIDUAL])
BACKBONE_PCC, BACKBONE_PDL, BACKBONE_POLYNOMIAL = 0, 1, 2
RESIDUAL_NONE, RESIDUAL_GRU, RESIDUAL_MLP = 0, 1, 2

# meta header: the kinds, whether the features hold the torques, the offset in
# buf of the raw step features, GRU layers and hidden size H, the offsets in
# buf of the gates' pre-activations (3H), of W_in x + b_in (H) and of a scratch
# vector (H), head layers, the offset in buf of the residual (3); the number of
# motors N, the channels of a sample (N, or 2N with torques), the offsets in f of
# the last sample, of the play's state, of the backbone's angles and of the
# neutral motor angles; the size of f and of buf (where an engine that
# stores them together, :class:`~skcath.online._jit.JitStep`, puts theta after f
# and w after buf); whether the compiled matrix products fuse their multiply-adds;
# the offsets in f of the Prandtl-Ishlinskii hysteresis's parameters, dead bands
# and state (0 without it)
(M_BACKBONE, M_RESIDUAL, M_USE_TORQUE, M_X, M_N_GRU, M_HIDDEN, M_GATES, M_CAND, M_TMP,
 M_N_HEAD, M_RESULT, M_N_MOTORS, M_N_CHANNELS, M_LAST, M_PLAY, M_ANGLES,
 M_NEUTRAL, M_THETA, M_W, M_FUSED, M_PI_THETA, M_PI_BANDS, M_PI_STATE,
 M_HEADER) = offsets(*(1,) * 23)

# matrix record: rows, columns, columns of the first block, then for each of
# the two column blocks whether it is stored in w32 and its offset (FlatStore)
# or index (MatrixStore); a matrix with one block has split == columns
(MAT_ROWS, MAT_COLS, MAT_SPLIT, MAT_A_W32, MAT_A_AT, MAT_B_W32, MAT_B_AT, MAT_RECORD) = offsets(
    1, 1, 1, 1, 1, 1, 1
)

# GRU layer record: inputs n_in, offset in buf of [x; 1; h], the gates' matrix
# (3H, n_in + 1 + H) on [x; 1; h], the candidate's matrix (H, n_in + 1) on [x; 1]
GRU_N_IN, GRU_VECTOR, GRU_GATES, GRU_CAND, GRU_RECORD = offsets(1, 1, MAT_RECORD, MAT_RECORD)

# head layer record: offset in buf of its input [1; a], of its output, whether
# tanh follows, the matrix [b, W]
HEAD_SRC, HEAD_DST, HEAD_TANH, HEAD_MATRIX, HEAD_RECORD = offsets(1, 1, 1, MAT_RECORD)

# f: nominal tip of the last step (3), clip (1), half-width of the play (1, deg;
# 0 without hysteresis, PI_FLAG with the Prandtl-Ishlinskii hysteresis), the
# square of the largest distance of accepted motor angles from the neutral
# angles (1, deg^2), the time since the previous step (1, s; read by the PI's
# creep); the regions sized by the motors follow from F_MOTORS (offsets in meta)
F_NOMINAL, F_CLIP, F_PLAY_WIDTH, F_LIMIT2, F_DT, F_MOTORS = offsets(3, 1, 1, 1, 1)
#: ``f[F_PLAY_WIDTH]`` of a step that runs the Prandtl-Ishlinskii hysteresis in
#: place of the play (any negative value does).
PI_FLAG = -1.0


@kernel
def without_hysteresis(f):
    """Switch off the hysteresis in front of the backbone in the step's array ``f``.

    The step then reads the angles of its sample as the effective angles.
    Called before each look-ahead evaluation, whose state is restored
    after it.
    """
    f[F_PLAY_WIDTH] = 0.0


class _Arena:
    """A flat array built piece by piece, handing out offsets."""

    def __init__(self, dtype):
        self.dtype = np.dtype(dtype)
        self.parts, self.size = [], 0

    def add(self, values):
        """Append ``values`` (column-major when 2-D); their offset."""
        at = self.size
        values = np.asarray(values).ravel(order="F").astype(self.dtype)
        self.parts.append(values)
        self.size += values.size
        return at

    def array(self):
        if not self.parts:
            return np.zeros(1, dtype=self.dtype)
        return np.concatenate(self.parts)


class FlatStore:
    """Matrices in two flat arrays, for the compiled step: ``w`` in the network's dtype, ``w32``.

    A block goes to ``w32`` (float32) when float32 holds its values exactly
    (weights the fitting left untouched, in float32): a float64 step then
    reads half the bytes and still multiplies exactly these values in
    float64. The blocks that absorbed the folded constants go to ``w``. A
    matrix is stored in two column blocks when ``split`` is less than its
    columns, so that the part that absorbed the constants does not keep the
    rest out of ``w32``.
    """

    def __init__(self, dtype):
        self.w, self.w32 = _Arena(dtype), _Arena(np.float32)

    def _block(self, M):
        if np.array_equal(M.astype(np.float32), M):
            return [1, self.w32.add(M)]
        return [0, self.w.add(M)]

    def add(self, M, split):
        """Store ``M``; its record from ``MAT_SPLIT`` on."""
        M = np.asarray(M)
        second = self._block(M[:, split:]) if split < M.shape[1] else [0, 0]
        return [split, *self._block(M[:, :split]), *second]

    def arrays(self):
        """``w`` and ``w32``."""
        return self.w.array(), self.w32.array()


class MatrixStore:
    """Matrices as a list of column-major arrays in the network's dtype, for the numpy step.

    Each matrix is one block, multiplied by one call of :func:`numpy.dot`
    (for these small shapes OpenBLAS ran faster on column-major arrays than
    on row-major ones); the record's offset is the index in the list.
    """

    def __init__(self, dtype):
        self.dtype = np.dtype(dtype)
        self.matrices = []

    def add(self, M, split):
        """Store ``M`` whole; its record from ``MAT_SPLIT`` on."""
        self.matrices.append(np.asfortranarray(M, dtype=self.dtype))
        return [M.shape[1], 0, len(self.matrices) - 1, 0, 0]

    def arrays(self):
        """The list of matrices, and None for ``w32``."""
        return self.matrices, None


def _gru_matrices(W_ih, W_hh, b_ih, b_hh):
    """The gates' matrix on ``[x; 1; h]`` and the candidate's on ``[x; 1]`` (PyTorch's gate order r, z, n).

    The gates' matrix gives the pre-activations of ``r`` and ``z`` and
    ``W_hn h + b_hn``; the candidate's gives ``W_in x + b_in``. No product
    involves a block of zeros larger than ``H x n_in``.
    """
    H = W_hh.shape[1]
    n_in = W_ih.shape[1]
    M = np.zeros((3 * H, n_in + 1 + H))
    M[: 2 * H, :n_in] = W_ih[: 2 * H]
    M[: 2 * H, n_in] = b_ih[: 2 * H] + b_hh[: 2 * H]
    M[: 2 * H, n_in + 1 :] = W_hh[: 2 * H]
    M[2 * H :, n_in] = b_hh[2 * H :]
    M[2 * H :, n_in + 1 :] = W_hh[2 * H :]
    return M, np.column_stack([W_ih[2 * H :], b_ih[2 * H :]])


class PackedStep:
    """The arrays of one run's step, laid out as this module names them.

    An engine's subclass sets ``engine`` (its name), ``store`` (:class:`FlatStore`
    or :class:`MatrixStore`) and ``_bind``, which returns :attr:`call`, and may
    set ``_merge``, which stores the arrays together and makes ``f``, ``theta``,
    ``w`` and ``buf`` views.

    Parameters
    ----------
    backbone : BackboneStep
        The backbone of the run: its kind, its packed calibration, its
        number of motors ``N`` and its play (half-width and the played
        angles of the last sweep sample) or its Prandtl-Ishlinskii
        hysteresis (``backbone.pi``, a :class:`~skcath.online._pi_stream.PIStep`).
    weights : StepWeights or None
        The residual's folded weights (:func:`~skcath.online._weights.step_weights`),
        or None for the backbone alone.
    clip : float
        Bound of each residual coordinate (mm); inf for none.
    use_torque : bool
        Whether the step features hold the torques.
    dtype : numpy dtype, default="float64"
        Arithmetic precision of the network.
    n_channels : int, default=None
        Channels of a sample: ``N`` motor angles, then ``N`` torques when the
        recordings have them; None means ``2N``.
    neutral : tuple of float, default=None
        Neutral motor angles (deg); None means zeros.
    limit2 : float, default=inf
        Square of the largest distance of accepted motor angles from
        ``neutral`` (deg^2): a step that checks its sample refuses one farther
        away, or with a channel that is not finite.

    Attributes
    ----------
    meta, f, theta, w, w32, buf : arrays
        As described in the module's docstring.
    call : callable
        The step on these arrays in the engine's form, ``call(out, sample,
        check)``: :func:`~skcath.online._kernels.step` with ``sample`` a tuple
        of ``n_channels`` floats.
    hidden : list of ndarray
        The GRU layers' hidden states (views of ``buf``).
    nominal : ndarray of shape (3,)
        Nominal tip of the last step (mm); a view of ``f``.
    last : ndarray of shape (n_channels,)
        Last accepted sample ``(q1 .. qN, tau1 .. tauN)``; a view of ``f``.
    play : ndarray of shape (N,)
        Played motor angles of the last step (deg); a view of ``f``.
    pi_state : ndarray of shape (N (K + 2),) or None
        State of the Prandtl-Ishlinskii hysteresis (``backbone.pi``), a view
        of ``f``; None without it.
    dt : ndarray of shape (1,) or None
        The time step (s) the hysteresis's creep reads at the next step
        (``f[F_DT]``), a view of ``f``; None without it.
    compile_seconds : float
        Time taken to compile the step (s).
    """

    def __init__(self, backbone, weights, clip, use_torque, dtype="float64", n_channels=None,
                 neutral=None, limit2=np.inf):
        self.dtype = np.dtype(np.float64 if weights is None else dtype)
        store = self.store(self.dtype)
        vectors = _Arena(self.dtype)
        header = np.zeros(M_HEADER, dtype=np.int64)
        header[M_BACKBONE] = backbone.code
        header[M_RESIDUAL] = RESIDUAL_NONE
        header[M_USE_TORQUE] = bool(use_torque)
        header[M_FUSED] = self.fused
        n_motors = backbone.n_motors
        n_channels = 2 * n_motors if n_channels is None else int(n_channels)
        header[M_N_MOTORS], header[M_N_CHANNELS] = n_motors, n_channels
        header[[M_LAST, M_PLAY, M_ANGLES, M_NEUTRAL]] = np.add(
            F_MOTORS, offsets(n_channels, n_motors, n_motors))
        gru, head, hidden = [], [], []
        if weights is not None:
            gru, src, hidden = self._pack_gru(weights.gru, header, vectors, store)
            if not gru:  # MLP: its input [1; x]
                src = vectors.add(np.r_[1.0, np.zeros(weights.head[0][0].shape[1])])
                header[M_X] = src + 1
            head = self._pack_head(weights.head, src, header, vectors, store)
            header[M_RESIDUAL] = RESIDUAL_GRU if gru else RESIDUAL_MLP
            header[M_N_GRU] = len(gru) // GRU_RECORD
            header[M_N_HEAD] = len(head) // HEAD_RECORD
        pi = self._pi = getattr(backbone, "pi", None)
        header[M_THETA] = header[M_NEUTRAL] + n_motors
        if pi is not None:
            header[[M_PI_THETA, M_PI_BANDS, M_PI_STATE, M_THETA]] = np.add(
                header[M_THETA], offsets(pi.theta.size, pi.bands.size, pi.start.size))
        self.meta = np.concatenate([header, np.asarray(gru + head, dtype=np.int64)])
        self.f = np.zeros(header[M_THETA])
        self.f[header[M_NEUTRAL] : header[M_NEUTRAL] + n_motors] = 0.0 if neutral is None else neutral
        self.f[F_LIMIT2] = limit2
        self.f[F_CLIP] = clip
        self.f[F_PLAY_WIDTH] = backbone.play_width
        if pi is not None:
            self.f[F_PLAY_WIDTH] = PI_FLAG
            self.f[F_DT] = pi.period
            self.f[header[M_PI_THETA] : header[M_PI_STATE]] = np.r_[pi.theta, pi.bands]
        self._play_start = backbone.play_start
        self.theta = backbone.theta
        self.w, self.w32 = store.arrays()
        self.buf = vectors.array()
        self.meta[M_W] = self.buf.size
        self._merge()
        self.hidden = [self.buf[at : at + n] for at, n in hidden]
        self.nominal = self.f[F_NOMINAL : F_NOMINAL + 3]
        self.last = self.f[header[M_LAST] : header[M_LAST] + n_channels]
        self.play = self.f[header[M_PLAY] : header[M_PLAY] + n_motors]
        self.play[:] = self._play_start
        self.pi_state = self.dt = None
        if pi is not None:
            self.pi_state = self.f[header[M_PI_STATE] : header[M_THETA]]
            self.pi_state[:] = pi.start
            self.dt = self.f[F_DT : F_DT + 1]
        self.call = self._bind()

    #: Whether the matrix products fuse their multiply-adds (``meta[M_FUSED]``;
    #: compiled code only).
    fused = False

    def _merge(self):
        """Hook of an engine that stores ``f`` and ``theta``, ``buf`` and ``w`` together (none)."""

    @staticmethod
    def _matrix(M, split, store):
        return [M.shape[0], M.shape[1], *store.add(M, split)]

    def _pack_gru(self, layers, header, vectors, store):
        """GRU records; the offset of the head's input ``[1; h]``; the hidden states' places."""
        records, hidden, src = [], [], 0
        for W_ih, W_hh, b_ih, b_hh in layers:
            H, n_in = W_hh.shape[1], W_ih.shape[1]
            gates, cand = _gru_matrices(W_ih, W_hh, b_ih, b_hh)
            at = vectors.add(np.r_[np.zeros(n_in), 1.0, np.zeros(H)])  # [x; 1; h]
            records += [n_in, at, *self._matrix(gates, n_in + 1, store),
                        *self._matrix(cand, n_in + 1, store)]
            hidden.append((at + n_in + 1, H))
            src = at + n_in  # [1; h] of the last layer
        if layers:
            header[M_X] = records[GRU_VECTOR]
            header[M_HIDDEN] = H
            header[M_GATES] = vectors.add(np.zeros(3 * H))
            header[M_CAND] = vectors.add(np.zeros(H))
            header[M_TMP] = vectors.add(np.zeros(H))
        return records, src, hidden

    def _pack_head(self, layers, src, header, vectors, store):
        """Head records, each layer on ``[1; a]``: tanh layers, then the output layer."""
        records = []
        for k, (W, b) in enumerate(layers):
            M = np.column_stack([b, W])
            rows, cols = M.shape
            if k < len(layers) - 1:  # hidden layer: tanh, output [1; a]
                dst = vectors.add(np.r_[1.0, np.zeros(rows)]) + 1
                records += [src, dst, 1, *self._matrix(M, cols, store)]
                src = dst - 1
            else:
                header[M_RESULT] = vectors.add(np.zeros(rows))
                records += [src, header[M_RESULT], 0, *self._matrix(M, cols, store)]
        return records

    def __call__(self, *sample_and_out):
        """Step with an accepted sample, ``step(*sample, out)``: the tip (mm) into ``out``."""
        *sample, out = sample_and_out
        self.call(out, tuple(sample), False)

    def reset(self, last_sample):
        """Zero hidden state; ``last_sample`` becomes the previous sample.

        The play and the Prandtl-Ishlinskii hysteresis go back to their
        states after the sweep.
        """
        for h in self.hidden:
            h[:] = 0.0
        self.last[:] = last_sample
        self.play[:] = self._play_start
        if self._pi is not None:
            self.pi_state[:] = self._pi.start
            self.dt[0] = self._pi.period
