// What every page shares: the one stream connection, shown by the
// connection indicator of the layout (templates/base.html).

import { Stream, streamUrl } from './stream.js';

export const stream = new Stream(streamUrl());

const indicator = document.getElementById('connection');
let countdown = null;

stream.onState(({ state, retryInMs, error }) => {
  if (error) {
    indicator.title = error;
    return;
  }
  clearInterval(countdown);
  indicator.dataset.state = state;
  indicator.title = '';
  if (state === 'connected') indicator.textContent = 'Live';
  else if (state === 'connecting') indicator.textContent = 'Connecting…';
  else {
    const until = Date.now() + retryInMs;
    const show = () => {
      const seconds = Math.max(0, Math.ceil((until - Date.now()) / 1000));
      indicator.textContent = `Disconnected · retry in ${seconds} s`;
    };
    show();
    countdown = setInterval(show, 1000);
  }
});
