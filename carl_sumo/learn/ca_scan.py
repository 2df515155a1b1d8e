"""Fused Communication-Aware passes: G networks of the same shape at once, with a hand-written
backward pass.

:class:`carl_sumo.learn.models.CommunicationAware` computes, for platoon inputs x (batch, n, in)::

    F_i = tanh(f_F(x_i, F_{i+1}))      tail -> head, F_n = forward_boundary (also for padding)
    (B_i, y_i) = f_B(F_i, B_{i-1})     head -> tail, B_{-1} = backward_boundary, B_i = tanh(...)

with 3-layer ReLU MLPs f_F, f_B. Done layer by layer under autograd that is about 25 small tensor
ops per vehicle forward and as many autograd nodes backward, for 128 platoon rows at a time. This
module computes the same function with fewer, larger ops:

- the input part of each first layer (x_i for f_F, F_i for f_B) is one matrix product over all
  (batch x vehicles) rows before the scan that needs it;
- the G networks (the twin critics) run side by side as batched products (``torch.baddbmm``) on
  weights stacked along a leading axis of size G;
- backward, only the message gradients are a scan (3 products per vehicle); every weight gradient
  is one product over all (batch x vehicles) rows afterwards;
- gradients that nobody needs are not computed (e.g. the critic's weights in the actor update:
  pass the critic's parameters detached).

Shapes: activations are stacked as (G, n, batch, width), so one vehicle is a (G, batch, width)
slice. The reference per-vehicle loop lives in tests/test_models.py; they agree to float32
rounding.
"""

from __future__ import annotations

import ctypes
from typing import Sequence

import torch
from torch import nn
from torch.autograd.function import once_differentiable

N_PARAMS = 14
"""Tensors per CA network, in :func:`ca_parameters` order."""

def keep_heap_memory(threshold_bytes: int = 32 << 20) -> None:
    """glibc only (elsewhere a no-op): serve allocations below ``threshold_bytes`` from the heap
    and keep freed heap memory, instead of mapping and unmapping the passes' large temporaries
    each update (which page-faults them in again: up to ~1.4 ms of a ~12 ms update)."""
    try:
        libc = ctypes.CDLL("libc.so.6")
        m_trim_threshold, m_mmap_threshold = -1, -3  # <malloc.h>
        libc.mallopt(m_mmap_threshold, threshold_bytes)
        libc.mallopt(m_trim_threshold, threshold_bytes)
    except (OSError, AttributeError):
        pass


def ca_parameters(net: nn.Module) -> list[torch.Tensor]:
    """The 14 parameters of a CommunicationAware network in the order :func:`ca_forward` takes:
    forward_boundary (M), backward_boundary (M), then W, b of f_F's three layers and of f_B's."""
    f, b = net.forward_net[0], net.backward_net
    return [net.forward_boundary, net.backward_boundary,
            f[0].weight, f[0].bias, f[2].weight, f[2].bias, f[4].weight, f[4].bias,
            b[0].weight, b[0].bias, b[2].weight, b[2].bias, b[4].weight, b[4].bias]


def _stacked(params: Sequence[torch.Tensor], g: int) -> list[torch.Tensor]:
    """Parameter k of every network stacked on a new axis 0 (a view when G = 1)."""
    if g == 1:
        return [p.unsqueeze(0) for p in params]
    return [torch.stack(params[k::N_PARAMS]) for k in range(N_PARAMS)]


def _rows(t: torch.Tensor) -> torch.Tensor:
    """(n, G, batch, k) -> (G, n*batch, k): every vehicle's rows of each network."""
    n, g, batch, k = t.shape
    if g == 1:
        return t.view(1, n * batch, k)
    return t.transpose(0, 1).reshape(g, n * batch, k)


def _layer_grads(d: torch.Tensor, inp: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Weight (G, out, in) and bias (G, out) gradients of a layer from the (n, G, batch, .)
    stacks of its output gradient ``d`` and its input (G may be 1: shared), summed over all
    rows."""
    rows = _rows(d)
    return torch.bmm(rows.transpose(1, 2), _rows(inp).expand(rows.shape[0], -1, -1)), rows.sum(1)


def _scan(x: torch.Tensor, mask: torch.Tensor | None, message_dim: int,
          w: list[torch.Tensor], save: bool) -> tuple[torch.Tensor, dict | None]:
    """Forward pass of G stacked networks; y (G, batch, n, out) and, if ``save``, what the
    backward pass needs. Activations are written into vehicle-major buffers (n, G, batch, .);
    the message buffers have one more row for the boundary."""
    fb, bb, fw1, fb1, fw2, fb2, fw3, fb3, bw1, bb1, bw2, bb2, bw3, bb3 = w
    g, m = fb.shape[0], message_dim
    batch, n, n_in = x.shape
    hidden = fw1.shape[1]
    xf = x.transpose(0, 1).reshape(n * batch, n_in)  # vehicle-major rows
    # input part of f_F's first layer for all vehicles at once: (G, n, batch, H)
    px = torch.baddbmm(fb1.unsqueeze(1), xf.expand(g, -1, -1), fw1[:, :, :n_in].transpose(1, 2))
    px = px.view(g, n, batch, hidden)
    w1, w2, w3 = (fw1[:, :, n_in:].transpose(1, 2), fw2.transpose(1, 2), fw3.transpose(1, 2))
    b2, b3 = fb2.unsqueeze(1), fb3.unsqueeze(1)
    h1, h2 = x.new_empty(n, g, batch, hidden), x.new_empty(n, g, batch, hidden)
    fm = x.new_empty(n + 1, g, batch, m)  # F_0 .. F_{n-1}, then the boundary
    fm[n] = fb.unsqueeze(1)
    keep = None if mask is None else mask.transpose(0, 1).unsqueeze(-1)  # (n, batch, 1)
    h1_, h2_, fm_, px_ = h1.unbind(0), h2.unbind(0), fm.unbind(0), px.unbind(1)  # step views
    for i in range(n - 1, -1, -1):  # tail -> head
        torch.baddbmm(px_[i], fm_[i + 1], w1, out=h1_[i]).relu_()
        torch.baddbmm(b2, h1_[i], w2, out=h2_[i]).relu_()
        torch.baddbmm(b3, h2_[i], w3, out=fm_[i]).tanh_()
        if keep is not None:  # a padded vehicle passes the boundary on
            fm_[i].copy_(torch.where(keep[i], fm_[i], fm_[n]))
    # f_B's first layer on F_i for all vehicles at once; f_B's last layer split into the
    # message rows (inside the scan) and the output rows (after it, for all vehicles at once)
    pf = torch.baddbmm(bb1.unsqueeze(1), _rows(fm[:n]), bw1[:, :, :m].transpose(1, 2))
    pf_ = pf.view(g, n, batch, hidden).unbind(1)
    w1, w2, w3 = (bw1[:, :, m:].transpose(1, 2), bw2.transpose(1, 2), bw3[:, :m].transpose(1, 2))
    b2, b3 = bb2.unsqueeze(1), bb3[:, :m].unsqueeze(1)
    k1, k2 = x.new_empty(n, g, batch, hidden), x.new_empty(n, g, batch, hidden)
    bm = x.new_empty(n + 1, g, batch, m)  # the boundary, then B_0 .. B_{n-1}
    bm[0] = bb.unsqueeze(1)
    k1_, k2_, bm_ = k1.unbind(0), k2.unbind(0), bm.unbind(0)
    for i in range(n):  # head -> tail
        torch.baddbmm(pf_[i], bm_[i], w1, out=k1_[i]).relu_()
        torch.baddbmm(b2, k1_[i], w2, out=k2_[i]).relu_()
        torch.baddbmm(b3, k2_[i], w3, out=bm_[i + 1]).tanh_()
    y = torch.baddbmm(bb3[:, m:].unsqueeze(1), _rows(k2), bw3[:, m:].transpose(1, 2))
    # (G, batch, n, out), contiguous as the per-vehicle loop's output was (randn_like of a tensor
    # computed from it draws in memory order)
    y = y.view(g, n, batch, -1).transpose(1, 2).contiguous()
    if not save:
        return y, None
    return y, {"xf": xf, "keep": keep, "fm": fm, "h1": h1, "h2": h2, "bm": bm, "k1": k1, "k2": k2}


def _scan_backward(dy: torch.Tensor, s: dict, w: list[torch.Tensor], message_dim: int,
                   weights: bool, inputs: bool) -> tuple[torch.Tensor | None, list | None]:
    """Gradients of the 14 stacked parameters (if ``weights``) and of x (if ``inputs``) from
    dy (G, batch, n, out)."""
    fb, bb, fw1, fb1, fw2, fb2, fw3, fb3, bw1, bb1, bw2, bb2, bw3, bb3 = w
    g, m = fb.shape[0], message_dim
    _, batch, n, _ = dy.shape
    n_in, hidden = s["xf"].shape[1], fw1.shape[1]
    relu_grad = torch.ops.aten.threshold_backward.grad_input
    tanh_grad = torch.ops.aten.tanh_backward.grad_input
    k1, k2, bm, h1, h2, fm = s["k1"], s["k2"], s["bm"], s["h1"], s["h2"], s["fm"]
    # f_B reversed (tail -> head). dy reaches k2 through the output rows of the last layer for
    # all vehicles at once; the message rows carry d(B_i) back one vehicle per step.
    dy_t = dy.permute(2, 0, 1, 3).contiguous()  # (n, G, batch, out)
    d_k2_out = torch.bmm(_rows(dy_t), bw3[:, m:]).view(g, n, batch, hidden).unbind(1)
    d1, d2 = dy.new_empty(n, g, batch, hidden), dy.new_empty(n, g, batch, hidden)
    d_pre = dy.new_empty(n, g, batch, m)  # d(pre-tanh B_i); B_{n-1} reaches nothing
    d_pre[n - 1] = 0.0
    k1_, k2_, bm_ = k1.unbind(0), k2.unbind(0), bm.unbind(0)
    d1_, d2_, d_pre_ = d1.unbind(0), d2.unbind(0), d_pre.unbind(0)
    w3m, w2, w1b = bw3[:, :m], bw2, bw1[:, :, m:]
    d_message = None  # d(B_i), from vehicle i + 1's step
    for i in range(n - 1, -1, -1):
        if d_message is None:
            relu_grad(d_k2_out[i], k2_[i], 0, grad_input=d2_[i])
        else:
            tanh_grad(d_message, bm_[i + 1], grad_input=d_pre_[i])
            relu_grad(torch.baddbmm(d_k2_out[i], d_pre_[i], w3m), k2_[i], 0, grad_input=d2_[i])
        relu_grad(torch.bmm(d2_[i], w2), k1_[i], 0, grad_input=d1_[i])
        d_message = torch.bmm(d1_[i], w1b)
    d_bb = d_message.sum(1)
    grads_b = [_layer_grads(d1, fm[:n]), _layer_grads(d1, bm[:n]), _layer_grads(d2, k1),
               _layer_grads(torch.cat([d_pre, dy_t], -1), k2)] if weights else []
    # into F_i from f_B, for all vehicles at once
    d_f = torch.bmm(_rows(d1), bw1[:, :, :m]).view(g, n, batch, m).unbind(1)
    # f_F reversed (head -> tail): d(F_i) = d_f[i] + what vehicle i - 1's step sends back
    keep = s["keep"]
    e1, e2 = dy.new_empty(n, g, batch, hidden), dy.new_empty(n, g, batch, hidden)
    e3, d_fm = dy.new_empty(n, g, batch, m), dy.new_empty(n + 1, g, batch, m)
    d_fm[0] = d_f[0]
    h1_, h2_, fm_ = h1.unbind(0), h2.unbind(0), fm.unbind(0)
    e1_, e2_, e3_, d_fm_ = e1.unbind(0), e2.unbind(0), e3.unbind(0), d_fm.unbind(0)
    w3, w2, w1m = fw3, fw2, fw1[:, :, n_in:]
    for i in range(n):
        tanh_grad(d_fm_[i], fm_[i], grad_input=e3_[i])
        if keep is not None:  # a padded vehicle's message is the boundary, not f_F's output
            e3_[i].mul_(keep[i])
        relu_grad(torch.bmm(e3_[i], w3), h2_[i], 0, grad_input=e2_[i])
        relu_grad(torch.bmm(e2_[i], w2), h1_[i], 0, grad_input=e1_[i])
        if i + 1 < n:
            torch.baddbmm(d_f[i + 1], e1_[i], w1m, out=d_fm_[i + 1])
        else:  # the tail's input message is the boundary
            torch.bmm(e1_[i], w1m, out=d_fm_[n])
    dx = None
    if inputs:
        dx = torch.bmm(_rows(e1), fw1[:, :, :n_in]).sum(0)  # (n*batch, in)
        dx = dx.view(n, batch, n_in).transpose(0, 1)
    if not weights:
        return dx, None
    d_fb = d_fm[n].sum(1)
    if keep is not None:  # padded vehicles pass the boundary on as their message
        d_fb = d_fb + (d_fm[:n] * ~keep.unsqueeze(1)).sum((0, 2))
    (dw1x, db1), (dw1m, _) = _layer_grads(e1, s["xf"].view(n, 1, batch, n_in)), \
        _layer_grads(e1, fm[1:])
    dw2, db2 = _layer_grads(e2, h1)
    dw3, db3 = _layer_grads(e3, h2)
    (dbw1f, dbb1), (dbw1b, _), (dbw2, dbb2), (dbw3, dbb3) = grads_b
    grads = [d_fb, d_bb, torch.cat([dw1x, dw1m], -1), db1, dw2, db2, dw3, db3,
             torch.cat([dbw1f, dbw1b], -1), dbb1, dbw2, dbb2, dbw3, dbb3]
    return dx, grads


class _CAFunction(torch.autograd.Function):
    """Autograd wrapper of :func:`_scan` / :func:`_scan_backward` over a flat parameter list."""

    @staticmethod
    def forward(ctx, x, mask, message_dim, *params):
        g = len(params) // N_PARAMS
        w = _stacked(params, g)
        y, saved = _scan(x, mask, message_dim, w, save=True)
        ctx.saved, ctx.w, ctx.message_dim, ctx.g = saved, w, message_dim, g
        return y

    @staticmethod
    @once_differentiable
    def backward(ctx, dy):
        weights = any(ctx.needs_input_grad[3:])
        dx, grads = _scan_backward(dy.contiguous(), ctx.saved, ctx.w, ctx.message_dim, weights,
                                   ctx.needs_input_grad[0])
        flat: list[torch.Tensor | None] = [None] * (ctx.g * N_PARAMS)
        if grads is not None:
            for k, grad in enumerate(grads):
                for j, part in enumerate(grad.unbind(0)):
                    flat[j * N_PARAMS + k] = part
        return (dx, None, None, *flat)


def ca_forward(nets: Sequence[nn.Module], x: torch.Tensor, mask: torch.Tensor | None = None,
               detach_params: bool = False) -> torch.Tensor:
    """Outputs (G, batch, n, out) of G CommunicationAware networks of one shape on the same
    inputs x (batch, n, in), padded vehicles (mask False) at the tail. ``detach_params``: no
    gradient to the networks' weights (gradients still reach x)."""
    params = [p for net in nets for p in ca_parameters(net)]
    if detach_params:
        params = [p.detach() for p in params]
    message_dim = nets[0].message_dim
    if mask is not None and bool(mask.all()):
        mask = None  # no padding: skip the per-vehicle select
    if torch.is_grad_enabled() and (x.requires_grad or any(p.requires_grad for p in params)):
        return _CAFunction.apply(x, mask, message_dim, *params)
    return _scan(x, mask, message_dim, _stacked(params, len(nets)), save=False)[0]
